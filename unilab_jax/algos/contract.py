"""The algorithm contract: what an algorithm's declaration module provides, and the ONE place that fills in
the defaults of its optional hooks.

A declaration is a module (``unilab_jax/algos/<family>/<name>.py``, registered in ``unilab_jax.algos``):

* what the runtime's workers read (:class:`RolloutDeclaration`): ``SYNC`` ("lockstep" | "async"),
  ``BUFFER`` ("trajectory" | "replay"), ``extras(action_dim)`` (the per-transition fields ``act`` writes
  besides the task's: ``{name: (shape, dtype)}``) and a shim-written ``act(weights, obs, noise,
  deterministic=False[, image=]) -> (action, extras)``;
* what the trainer and the CLI add (:class:`Declaration`): ``Config`` (a frozen dataclass, every field a
  ``--config`` key; it validates its own fields in ``__post_init__``; :class:`LoopConfig` /
  :class:`ReplayLoopConfig` are the fields the training loop reads) and ``make_learner(platform, config, spec)``;
* optional hooks, read only through :func:`hooks` (never ``getattr`` on a declaration elsewhere):

  ``NOISE_HOLD_STEPS``        control steps a worker holds each exploration-noise draw (FlashSAC; default 1)
  ``noise_dim(action_dim)``   standard normals a worker draws per env step (SAC Flow; default ``action_dim``)
  ``IMAGES``                  learns from image observations (``offpolicy/image_obs``; default False)
  ``PRIOR_DATA``              its ``Config`` has ``prior_dir``/``prior_fraction`` and the trainer mixes prior data
                              into the minibatches (RLPD; default False)
  ``check_run(platform, task_config, config)``  the algorithm's own flag checks before anything starts
                              (ValueError with the reason; default none)
  SAC-family learner hooks (:class:`SACFamilyDeclaration`: ``init_params``, ``critic_loss``, ``actor_loss``,
  ``temperature_loss`` required):
  ``learner_noise_dim(config, action_dim)``  standard normals per sample of the learner's policy draw
                              (SAC Flow; default ``action_dim``)
  ``project_params(params)``  applied to the actor, critic and target critic after every step (FlashSAC)
  ``reward_scale(stats, config)``  rewards are divided by it (FlashSAC; default: none, a scale of 1)
  ``critic_noise_shape(config)``  shape of a uniform draw per gradient step passed with ``eps_next`` to the
                              critic loss (RLPD; default: none)
  ``actor_every(config)``     critic steps per actor and temperature step (RLPD; default 1)

This module is pure standard library and sits in layer 1 (``tests/test_layers.py``), below the runtime, so the
workers read the hooks of the declaration they were handed here without importing the registry.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from types import ModuleType
from typing import Any, Protocol, runtime_checkable

SYNC_KINDS = ("lockstep", "async")
BUFFER_KINDS = ("trajectory", "replay")
# The attributes each level of the contract requires (the Protocols below, as names, for error messages).
ROLLOUT_ATTRIBUTES = ("SYNC", "BUFFER", "extras", "act")
DECLARATION_ATTRIBUTES = ROLLOUT_ATTRIBUTES + ("Config", "make_learner")
SAC_FAMILY_ATTRIBUTES = ("init_params", "critic_loss", "actor_loss", "temperature_loss")


@runtime_checkable
class RolloutDeclaration(Protocol):
    """What the runtime's workers read from an algorithm module (``runtime.pool.load_algo`` checks it)."""

    SYNC: str
    BUFFER: str

    def extras(self, action_dim: int) -> dict[str, tuple[tuple[int, ...], Any]]: ...

    def act(self, weights: Any, obs: Any, noise: Any, deterministic: bool = False) -> tuple[Any, dict]: ...


@runtime_checkable
class Declaration(RolloutDeclaration, Protocol):
    """What every registered algorithm's declaration provides."""

    Config: type

    def make_learner(self, platform: str, config: Any, spec: Any) -> Any: ...


@runtime_checkable
class SACFamilyDeclaration(Declaration, Protocol):
    """A declaration the SAC-family learners run (``offpolicy/learner_jax``, ``learner_mlx``): shim-written
    losses with the signatures of ``offpolicy/sac.py``'s."""

    def init_params(self, key: Any, obs_dim: int, critic_obs_dim: int, action_dim: int, config: Any,
                    xp: Any) -> dict: ...

    def critic_loss(self, critic: Any, target_critic: Any, actor: Any, log_alpha: Any, norms: Any, mb: dict,
                    eps_next: Any, config: Any) -> tuple[Any, dict]: ...

    def actor_loss(self, actor: Any, critic: Any, log_alpha: Any, norms: Any, mb: dict, eps: Any,
                   config: Any) -> tuple[Any, tuple]: ...

    def temperature_loss(self, log_alpha: Any, log_prob: Any, target_entropy: float) -> Any: ...


@runtime_checkable
class LoopConfig(Protocol):
    """The ``Config`` fields every training loop reads: ``horizon``, control steps per worker chunk (a
    trajectory slot's length; an off-policy worker's bookkeeping unit)."""

    horizon: int


@runtime_checkable
class ReplayLoopConfig(LoopConfig, Protocol):
    """The fields the training loops read from an off-policy (``BUFFER == "replay"``) ``Config``; the learner
    reads ``batch_size`` and ``updates_per_call`` too (the rest of the fields are the learner's alone)."""

    utd: float
    updates_per_call: int
    batch_size: int
    replay_capacity: int
    learning_starts: int
    publish_every: int


def missing(declaration: Any, attributes: tuple[str, ...] = ROLLOUT_ATTRIBUTES) -> list[str]:
    """The required ``attributes`` that ``declaration`` lacks (empty: it satisfies that level)."""
    return [name for name in attributes if not hasattr(declaration, name)]


def _identity(params: Any) -> Any:
    return params


def _action_dim(action_dim: int) -> int:
    return action_dim


def _learner_action_dim(config: Any, action_dim: int) -> int:
    return action_dim


def _no_check(platform: str, task_config: Any, config: Any) -> None:
    return None


def _every_step(config: Any) -> int:
    return 1


@dataclasses.dataclass(frozen=True)
class Hooks:
    """A declaration's optional hooks with their defaults filled in (see the module docstring)."""

    noise_hold_steps: int = 1
    noise_dim: Callable[[int], int] = _action_dim
    images: bool = False
    prior_data: bool = False
    check_run: Callable[[str, Any, Any], None] = _no_check
    learner_noise_dim: Callable[[Any, int], int] = _learner_action_dim
    project_params: Callable[[Any], Any] | None = None  # None: nothing to project
    reward_scale: Callable[[Any, Any], Any] | None = None  # None: rewards unscaled, no reward statistics
    critic_noise_shape: Callable[[Any], tuple[int, ...]] | None = None  # None: the critic loss gets eps_next only
    actor_every: Callable[[Any], int] = _every_step

    @property
    def project(self) -> Callable[[Any], Any]:
        """``project_params`` or the identity."""
        return self.project_params or _identity


# hook attribute of a declaration -> Hooks field
_HOOKS = {"NOISE_HOLD_STEPS": "noise_hold_steps", "noise_dim": "noise_dim", "IMAGES": "images",
          "PRIOR_DATA": "prior_data", "check_run": "check_run", "learner_noise_dim": "learner_noise_dim",
          "project_params": "project_params", "reward_scale": "reward_scale",
          "critic_noise_shape": "critic_noise_shape", "actor_every": "actor_every"}
HOOK_NAMES = tuple(_HOOKS)


def hooks(declaration: ModuleType | Any) -> Hooks:
    """The optional hooks ``declaration`` defines, defaults for the rest (the only place they are looked up)."""
    found = {field: getattr(declaration, name) for name, field in _HOOKS.items() if hasattr(declaration, name)}
    if "noise_hold_steps" in found:
        found["noise_hold_steps"] = max(int(found["noise_hold_steps"]), 1)
    for flag in ("images", "prior_data"):
        if flag in found:
            found[flag] = bool(found[flag])
    return Hooks(**found)
