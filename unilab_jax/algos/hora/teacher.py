"""HORA stage 1: a PPO teacher whose policy sees the current frame and z = tanh(mlp(extrinsics)).

Lock-step PPO on trajectory slots (exactly PPO's schedule and update, see ``ppo_jax.Learner``'s
hooks); only the policy input differs. Needs a ``<task>_hist`` task with ``history_extrinsics=True``
(``tasks/history.py``); ``history_len=1`` is enough. The critic sees the task's critic observation,
to which that variant appends the extrinsics. Published weights: ``{"actor", "encoder", "log_std",
"obs_norm"}``. JAX learner only (see ``check_run``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from unilab_jax.algos.hora import common as hora
from unilab_jax.algos.ppo.ppo import PPOConfig, extras, gaussian_act
from unilab_jax.lazy import learner_maker

SYNC = "lockstep"
BUFFER = "trajectory"

__all__ = ["SYNC", "BUFFER", "Config", "act", "extras", "make_learner", "check_run", "check_spec"]


@dataclasses.dataclass(frozen=True)
class HoraTeacherConfig(PPOConfig):
    """PPO's hyperparameters plus the extrinsics encoder (HORA: MLP 256-128-8, tanh output)."""

    encoder_hidden: tuple[int, ...] = (256, 128)
    z_dim: int = 8


Config = HoraTeacherConfig
make_learner = learner_maker(__name__)


def act(weights: dict[str, Any], obs: Any, noise: Any, deterministic: bool = False) -> tuple[Any, dict]:
    """Gaussian policy on [frame, z]. obs [M, H d + p], noise [M, A] -> action [M, A], PPO's extras."""
    return gaussian_act(hora.teacher_actor, weights, obs, noise, deterministic)


def check_run(platform: str, task_config: Any, config: Any) -> None:
    """Flag checks before anything starts (``cli.build_run``): ValueError with the reason."""
    hora.check_run("hora_teacher", platform, task_config, "a task variant with extrinsics in the observation: a "
                   "'<task>_hist' task (tasks/history.py) with history_extrinsics=True")


def check_spec(spec: Any) -> None:
    hora.check_spec("hora_teacher", spec)
