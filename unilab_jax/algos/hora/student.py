"""HORA stage 2: the adaptation module, trained by regression while the student drives the robot.

Not PPO. The workers act with the frozen teacher policy head on ``[frame, z_hat]``, ``z_hat`` from
the adaptation module on the last ``H`` frames (by default the action mean, as HORA's stage 2 does;
``action_noise`` adds that fraction of the teacher's exploration noise). The learner only fits the
adaptation module: ``mean((z_hat - z)^2)`` with ``z`` the frozen teacher encoder's latent of each
transition's extrinsics (``core.hora.adaptation_loss``); no rewards, values or log-probs are used,
so the policy declares no extras.

Schedule: **async** workers on **trajectory** slots. The regression target depends on the state only,
not on which policy version produced the action, so data a few versions old is as good a target
as fresh data (no importance correction, unlike PPO); it is still the student's *own* state
distribution (DAgger-style), which a replay buffer of old rollouts would drift away from. Async
lets the workers keep stepping while the learner fits; each batch is then used for
``num_epochs`` x ``num_minibatches`` Adam steps and discarded.

The student starts from the teacher's last checkpoint (``teacher_checkpoint``: its checkpoints
folder); its own checkpoints hold the frozen teacher pieces too, so a resumed student needs the
teacher folder only to build its initial state. Published weights: ``{"actor", "log_std",
"adapt", "history_norm", "noise_scale"}``; the extrinsics in the observation are never read by
``act`` (tested). Task: the teacher's ``<task>_hist`` variant with ``history_len = H`` long
enough for the temporal convolutions (30 by default, HORA's). JAX learner only.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from unilab_jax import xp as shim
from unilab_jax.algos.hora import common as hora
from unilab_jax.lazy import learner_maker

SYNC = "async"
BUFFER = "trajectory"

__all__ = ["SYNC", "BUFFER", "Config", "act", "extras", "make_learner", "check_run", "check_spec"]


@dataclasses.dataclass(frozen=True)
class HoraStudentConfig:
    """Adaptation-module training (HORA's ProprioAdaptTConv: per-step MLP 32-32, temporal convolutions of
    32 channels with kernels 9 (stride 2), 5, 5, linear projection to z)."""

    teacher_checkpoint: str = ""  # the teacher run's checkpoints folder (required)
    adapt_hidden: tuple[int, ...] = (32, 32)
    conv_channels: int = 32
    conv_kernels: tuple[int, ...] = (9, 5, 5)
    learning_rate: float = 1e-3
    max_grad_norm: float = 1.0
    horizon: int = 24  # control steps per trajectory slot
    num_epochs: int = 2
    num_minibatches: int = 4
    action_noise: float = 0.0  # fraction of the teacher's exploration std the student acts with


Config = HoraStudentConfig
make_learner = learner_maker(__name__)


def extras(action_dim: int) -> dict[str, tuple[tuple[int, ...], str]]:
    """The student's transitions need no policy fields: the learner recomputes everything it fits."""
    return {}


def act(weights: dict[str, Any], obs: Any, noise: Any, deterministic: bool = False) -> tuple[Any, dict]:
    """Teacher head on [frame, z_hat]. obs [M, H d + p] (extrinsics unread), noise [M, A] -> action [M, A]."""
    xp = shim.namespace(obs)
    z_hat, frames = hora.student_latent(weights["adapt"], weights["history_norm"], obs)
    mean = hora.policy_mean(weights["actor"], frames[..., -1, :], z_hat)
    if deterministic:
        return mean, {}
    return mean + weights["noise_scale"] * xp.exp(weights["log_std"]) * noise, {}


def check_run(platform: str, task_config: Any, config: HoraStudentConfig) -> None:
    """Flag checks before anything starts (``cli.build_run``): ValueError with the reason."""
    hora.check_run("hora_student", platform, task_config, "the teacher's '<task>_hist' task variant with "
                   "history_extrinsics=True (the extrinsics are the regression target's input, never the policy's)")
    if not config.teacher_checkpoint:
        raise ValueError("hora_student needs teacher_checkpoint (the teacher run's checkpoints folder)")


def check_spec(spec: Any) -> None:
    hora.check_spec("hora_student", spec)
