"""A tiny real algorithm module for runtime tests: linear Gaussian policy written with numpy.

Weights: ``{"w": [action_dim, obs_dim], "log_std": [action_dim]}``; ``act`` returns
``action = w @ obs + exp(log_std) * noise`` (batched: ``obs @ w.T``) and its log-probability.
"""

from __future__ import annotations

import numpy as np

SYNC = "lockstep"
BUFFER = "trajectory"


def extras(action_dim: int) -> dict:
    return {"log_prob": ((), np.float32)}


def init_weights(obs_dim: int, action_dim: int, value: float = 0.0) -> dict:
    return {"w": np.full((action_dim, obs_dim), value, np.float32), "log_std": np.full((action_dim,), -0.5, np.float32)}


def act(params: dict, obs: np.ndarray, noise: np.ndarray, deterministic: bool = False):
    mean = obs @ params["w"].T
    std = np.exp(params["log_std"])
    action = mean if deterministic else mean + std * noise
    log_prob = -0.5 * np.sum(np.square((action - mean) / std) + 2 * params["log_std"] + np.log(2 * np.pi), axis=-1)
    return action.astype(np.float32), {"log_prob": log_prob.astype(np.float32)}
