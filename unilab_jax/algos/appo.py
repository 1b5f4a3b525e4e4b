"""APPO: asynchronous PPO. Workers never wait for weights; V-trace corrects the policy lag and the
policy loss uses Sample Factory's asymmetric ratio clip [1/(1+eps), 1+eps]."""

from __future__ import annotations

import dataclasses

from tasks.base import TaskSpec
from unilab_jax.algos.ppo import PPOConfig, act, extras

SYNC = "async"
BUFFER = "trajectory"
Config = dataclasses.make_dataclass("APPOConfig", [], bases=(PPOConfig,), frozen=True)
Config.__doc__ = "APPO hyperparameters: PPO's, with V-trace targets instead of GAE."

__all__ = ["SYNC", "BUFFER", "Config", "act", "extras", "make_learner"]


def make_learner(platform: str, config: PPOConfig, spec: TaskSpec):
    if platform == "jax":
        from unilab_jax.algos.ppo_jax import Learner

        return Learner(config, spec, use_vtrace=True)
    elif platform == "mlx":
        from unilab_mlx.ppo import Learner

        return Learner(config, spec, use_vtrace=True)
    raise ValueError(f"APPO has no learner for platform {platform!r} yet")
