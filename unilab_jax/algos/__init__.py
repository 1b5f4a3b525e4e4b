"""Algorithm registry (open: ``register(name, module_path)`` adds one defined elsewhere).

An algorithm module declares ``SYNC``, ``BUFFER``, ``Config``, ``extras(action_dim)``, a shim-written
``act(weights, obs, noise, deterministic)`` for the workers and ``make_learner(platform, config,
spec)`` for the learner (see docs/ARCHITECTURE.md).
"""

from __future__ import annotations

import importlib
from types import ModuleType

# Transition fields a learner's batch holds, by buffer kind (the trainer sends these; learners read them).
TRAJECTORY_FIELDS = ("obs", "critic_obs", "next_critic_obs", "action", "reward", "terminated", "truncated",
                     "log_prob", "mean", "log_std")  # [T, B, ...]
REPLAY_FIELDS = ("obs", "critic_obs", "action", "reward", "next_obs", "next_critic_obs", "terminated",
                 "truncated")  # [U, B, ...]

_ALGORITHMS: dict[str, str] = {
    "ppo": "unilab_jax.algos.ppo",
    "appo": "unilab_jax.algos.appo",
    "sac": "unilab_jax.algos.sac",
    "td3": "unilab_jax.algos.td3",
    "fastsac": "unilab_jax.algos.fastsac",
    "flashsac": "unilab_jax.algos.flashsac",
    "hora_teacher": "unilab_jax.algos.hora_teacher",
    "hora_student": "unilab_jax.algos.hora_student",
    "him_ppo": "unilab_jax.algos.him_ppo",
}


def register(name: str, module_path: str) -> None:
    _ALGORITHMS[name] = module_path


def names() -> list[str]:
    return sorted(_ALGORITHMS)


def get(name: str) -> ModuleType:
    if name not in _ALGORITHMS:
        raise ValueError(f"unknown algorithm {name!r}; registered: {names()}")
    return importlib.import_module(_ALGORITHMS[name])
