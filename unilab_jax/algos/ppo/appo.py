"""APPO: asynchronous PPO. Workers never wait for weights; V-trace corrects the policy lag and the
policy loss uses Sample Factory's asymmetric ratio clip [1/(1+eps), 1+eps]."""

from __future__ import annotations

import dataclasses

from unilab_jax.algos.ppo.ppo import PPOConfig, act, extras
from unilab_jax.lazy import learner_maker

SYNC = "async"
BUFFER = "trajectory"
VTRACE = True
Config = dataclasses.make_dataclass("APPOConfig", [], bases=(PPOConfig,), frozen=True)
Config.__doc__ = "APPO hyperparameters: PPO's, with V-trace targets instead of GAE."
make_learner = learner_maker(__name__)

__all__ = ["SYNC", "BUFFER", "VTRACE", "Config", "act", "extras", "make_learner"]
