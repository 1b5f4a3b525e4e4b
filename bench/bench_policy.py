"""The policy the throughput benchmark runs in its workers: a 512-256-128 ELU MLP Gaussian in numpy.

An algorithm module as the runtime expects it (``SYNC``, ``BUFFER``, ``extras``, ``act``); weights
carry observation-normalizer statistics like PPO's. Asynchronous, trajectory slots.
"""

from __future__ import annotations

import numpy as np

from unilab_jax import nets
from unilab_jax import xp as shim

SYNC = "async"
BUFFER = "trajectory"


def extras(action_dim: int) -> dict:
    return {"log_prob": ((), np.float32)}


def init_weights(obs_dim: int, action_dim: int, hidden=(512, 256, 128), seed: int = 0) -> dict:
    xp = shim.get("numpy")
    actor = nets.init(xp.random.key(seed), [obs_dim, *hidden, action_dim], xp, final_scale=0.01)
    actor = [{k: np.asarray(v, np.float32) for k, v in layer.items()} for layer in actor]
    return {"actor": actor, "log_std": np.zeros(action_dim, np.float32),
            "obs_norm": {"mean": np.zeros(obs_dim, np.float32), "var": np.ones(obs_dim, np.float32)}}


def act(params: dict, obs: np.ndarray, noise: np.ndarray, deterministic: bool = False):
    norm = params["obs_norm"]
    x = np.clip((obs - norm["mean"]) / np.sqrt(norm["var"] + 1e-8), -10.0, 10.0)
    mean = nets.apply(params["actor"], x)
    log_std = params["log_std"]
    action = mean if deterministic else mean + np.exp(log_std) * noise
    log_prob = -0.5 * np.sum(np.square(noise) + 2 * log_std + np.log(2 * np.pi), axis=-1)
    return action.astype(np.float32), {"log_prob": log_prob.astype(np.float32)}
