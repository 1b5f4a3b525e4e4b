"""Algorithm registry (open: ``register(name, module_path, learners)`` adds one defined elsewhere).

Two tables, both of module paths, imported only when asked for (a Mac without jax never imports a
JAX learner): algorithm name -> declaration module (``SYNC``, ``BUFFER``, ``Config``, ``extras``, a
shim-written ``act`` for the workers; see docs/ARCHITECTURE.md) and (algorithm, platform) ->
``"module:factory"``, ``factory(declaration, config, spec) -> learner``. Each family keeps its
declarations and learners in one folder: ``ppo/`` (PPO, APPO, HIM-PPO), ``offpolicy/`` (SAC, TD3,
FastSAC, FlashSAC, RLPD, SAC Flow, RLPD Flow) and ``hora/`` (teacher and student).

What a declaration provides, and the defaults of its optional hooks, is ``contract``'s. A third table records
what the code does not say: each algorithm's family and the update its learners run; :func:`info` combines it
with the declaration's contract (sync, buffer, images, prior data) and the learners' platforms, and callers ask
``info`` instead of probing a declaration's attributes.
"""

from __future__ import annotations

import dataclasses
import importlib
from types import ModuleType
from typing import Any

from unilab_jax.algos import contract
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
    "rlpd_flow": f"{_OFF}.rlpdflow",
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
    "rlpd_flow": _SAC_FAMILY,
    "sacflow": _SAC_FAMILY,
    "hora_teacher": {"jax": f"{_HORA}.learner_jax:make_teacher_learner"},
    "hora_student": {"jax": f"{_HORA}.learner_jax:make_student_learner"},
}

FAMILIES = ("on_policy", "off_policy", "distillation")
# name -> (family, the update its learners run, flow policy): "ppo" (PPO's clipped update; HORA's teacher and
# HIM-PPO add to it), "sac" (the SAC-family learner: soft actor-critic with automatic temperature), "td3",
# "adaptation" (HORA's student: regression onto the frozen teacher's latent).
_KINDS: dict[str, tuple[str, str, bool]] = {
    "ppo": ("on_policy", "ppo", False),
    "appo": ("on_policy", "ppo", False),
    "him_ppo": ("on_policy", "ppo", False),
    "sac": ("off_policy", "sac", False),
    "td3": ("off_policy", "td3", False),
    "fastsac": ("off_policy", "sac", False),
    "flashsac": ("off_policy", "sac", False),
    "rlpd": ("off_policy", "sac", False),
    "rlpd_flow": ("off_policy", "sac", True),
    "sacflow": ("off_policy", "sac", True),
    "hora_teacher": ("on_policy", "ppo", False),
    "hora_student": ("distillation", "adaptation", False),
}


@dataclasses.dataclass(frozen=True)
class AlgorithmInfo:
    """What an algorithm is and can do (:func:`info`).

    ``family``: "on_policy" | "off_policy" | "distillation"; ``update``: the update its learners run ("ppo",
    "sac" for every algorithm the SAC-family learner runs, "td3", "adaptation", or a registered one's own);
    ``sync``/``buffer``: the declaration's ``SYNC``/``BUFFER``; ``platforms``: those with a learner;
    ``images``: learns from image observations; ``prior_data``: mixes prior data (``prior_dir``) into its
    minibatches; ``flow_policy``: its policy is a flow (workers draw ``noise_dim(A)`` normals)."""

    name: str
    module: str
    family: str
    update: str
    sync: str
    buffer: str
    platforms: tuple[str, ...]
    images: bool
    prior_data: bool
    flow_policy: bool


def register(name: str, module_path: str, learners: dict[str, str] | None = None, *, family: str | None = None,
             update: str | None = None, flow_policy: bool = False) -> None:
    """Adds (or replaces) algorithm ``name``: its declaration module and its learner factories by
    platform, ``{"jax": "package.module:factory"}`` with ``factory(declaration, config, spec)``.

    ``family`` defaults to the declaration's buffer ("off_policy" for replay, else "on_policy"), ``update`` to
    ``name`` (pass ``update="sac"`` for a declaration the SAC-family learner runs)."""
    if family is not None and family not in FAMILIES:
        raise ValueError(f"family must be one of {FAMILIES}, got {family!r}")
    _ALGORITHMS[name] = module_path
    _LEARNERS[name] = dict(learners or {})
    _KINDS[name] = (family or "", update or name, bool(flow_policy))


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


def info(algo: str | ModuleType) -> AlgorithmInfo:
    """The family and capabilities of ``algo`` (name, declaration module or its path); imports the declaration."""
    name = _name_of(algo)
    declaration = get(name)
    lacking = contract.missing(declaration, contract.DECLARATION_ATTRIBUTES)
    if lacking:
        raise ValueError(f"algorithm {name!r} ({_ALGORITHMS[name]}) lacks {lacking} (see unilab_jax/algos/contract.py)")
    family, update, flow_policy = _KINDS.get(name, ("", name, False))
    hooks = contract.hooks(declaration)
    return AlgorithmInfo(
        name=name, module=_ALGORITHMS[name],
        family=family or ("off_policy" if declaration.BUFFER == "replay" else "on_policy"), update=update,
        sync=declaration.SYNC, buffer=declaration.BUFFER, platforms=tuple(sorted(_LEARNERS.get(name, {}))),
        images=hooks.images, prior_data=hooks.prior_data, flow_policy=flow_policy)


def make_learner(algo: str | ModuleType, platform: str, config: Any, spec: Any) -> Any:
    """The learner of ``algo`` (name, declaration module or its path) for ``platform``."""
    name = _name_of(algo)
    factories = _LEARNERS.get(name, {})
    if platform not in factories:
        raise ValueError(f"{name} has no learner for platform {platform!r} (has: {sorted(factories) or 'none'})")
    return load(factories[platform])(get(name), config, spec)
