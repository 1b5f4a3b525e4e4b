"""Algorithm registry (open: ``register(name, module_path, learners)`` adds one defined elsewhere).

Two tables, both of module paths, imported only when asked for (a Mac without jax never imports a
JAX learner): algorithm name -> declaration module (``SYNC``, ``BUFFER``, ``Config``, ``extras``, a
shim-written ``act`` for the workers; see docs/ARCHITECTURE.md) and (algorithm, platform) ->
``"module:factory"``, ``factory(declaration, config, spec) -> learner``. Each family keeps its
declarations and learners in one folder: ``ppo/`` (PPO, APPO, HIM-PPO), ``offpolicy/`` (SAC, TD3,
FastSAC, FlashSAC, RLPD, SAC Flow) and ``hora/`` (teacher and student).
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

from unilab_jax.lazy import load

_PPO, _OFF, _HORA = "unilab_jax.algos.ppo", "unilab_jax.algos.offpolicy", "unilab_jax.algos.hora"
_SAC_FAMILY = {"jax": f"{_OFF}.learner_jax:SACFamilyLearner", "mlx": f"{_OFF}.learner_mlx:SACFamilyLearner"}

_ALGORITHMS: dict[str, str] = {
    "ppo": f"{_PPO}.ppo",
    "appo": f"{_PPO}.appo",
    "him_ppo": f"{_PPO}.him_ppo",
    "sac": f"{_OFF}.sac",
    "td3": f"{_OFF}.td3",
    "fastsac": f"{_OFF}.fastsac",
    "flashsac": f"{_OFF}.flashsac",
    "rlpd": f"{_OFF}.rlpd",
    "sacflow": f"{_OFF}.sacflow",
    "hora_teacher": f"{_HORA}.teacher",
    "hora_student": f"{_HORA}.student",
}
_LEARNERS: dict[str, dict[str, str]] = {
    "ppo": {"jax": f"{_PPO}.learner_jax:make_learner", "mlx": f"{_PPO}.learner_mlx:make_learner"},
    "appo": {"jax": f"{_PPO}.learner_jax:make_learner", "mlx": f"{_PPO}.learner_mlx:make_learner"},
    "him_ppo": {"jax": f"{_PPO}.him_ppo_jax:make_learner"},
    "sac": _SAC_FAMILY,
    "td3": {"jax": f"{_OFF}.learner_jax:make_td3_learner", "mlx": f"{_OFF}.learner_mlx:make_td3_learner"},
    "fastsac": _SAC_FAMILY,
    "flashsac": _SAC_FAMILY,
    "rlpd": _SAC_FAMILY,
    "sacflow": _SAC_FAMILY,
    "hora_teacher": {"jax": f"{_HORA}.learner_jax:make_teacher_learner"},
    "hora_student": {"jax": f"{_HORA}.learner_jax:make_student_learner"},
}


def register(name: str, module_path: str, learners: dict[str, str] | None = None) -> None:
    """Adds (or replaces) algorithm ``name``: its declaration module and its learner factories by
    platform, ``{"jax": "package.module:factory"}`` with ``factory(declaration, config, spec)``."""
    _ALGORITHMS[name] = module_path
    _LEARNERS[name] = dict(learners or {})


def names() -> list[str]:
    return sorted(_ALGORITHMS)


def get(name: str) -> ModuleType:
    if name not in _ALGORITHMS:
        raise ValueError(f"unknown algorithm {name!r}; registered: {names()}")
    return importlib.import_module(_ALGORITHMS[name])


def _name_of(algo: str | ModuleType) -> str:
    """A registered name from a name, a declaration module or its module path."""
    path = algo.__name__ if isinstance(algo, ModuleType) else algo
    if path in _ALGORITHMS:
        return path
    for name, module_path in _ALGORITHMS.items():
        if module_path == path:
            return name
    raise ValueError(f"unknown algorithm {path!r}; registered: {names()}")


def make_learner(algo: str | ModuleType, platform: str, config: Any, spec: Any) -> Any:
    """The learner of ``algo`` (name, declaration module or its path) for ``platform``."""
    name = _name_of(algo)
    factories = _LEARNERS.get(name, {})
    if platform not in factories:
        raise ValueError(f"{name} has no learner for platform {platform!r} (has: {sorted(factories) or 'none'})")
    return load(factories[platform])(get(name), config, spec)
