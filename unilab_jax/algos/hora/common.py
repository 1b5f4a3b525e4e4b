"""HORA (Qi et al., arXiv 2210.04887): what the teacher and the student share (shim-written).

Two algorithms, two stages, on a ``<task>_hist`` task variant (``tasks/history.py``) whose
observation is ``[H frames of d features | p extrinsics]``:

* ``hora_teacher`` (stage 1, :mod:`unilab_jax.algos.hora_teacher`): PPO whose policy sees the
  current frame and ``z = tanh(mlp(extrinsics))``; the encoder learns end to end through the policy
  gradient. Trained with ``history_len=1`` (the teacher needs no history, and frames cost storage).
* ``hora_student`` (stage 2, :mod:`unilab_jax.algos.hora_student`): an adaptation module
  (``unilab_jax.nets_temporal``) predicts ``z_hat`` from the last ``H`` frames; the workers act with
  the *frozen* teacher policy head on ``[frame, z_hat]``; the learner regresses ``z_hat`` onto the
  frozen teacher encoder's ``z`` (``core.hora.adaptation_loss``).

Dimensions come from array shapes, so the worker-side ``act`` needs no config: the teacher's
``p`` is its encoder's input size, ``Z`` its output size and ``d`` the policy input minus ``Z``; the
student's ``H`` and ``d`` are the shape of its per-position history normalizer ``[H, d]``.
Normalisation: the teacher's running statistics cover its stage-1 observation; the columns of its
last frame normalise every frame (and the current one) in both stages, its extrinsics columns the
extrinsics.
"""

from __future__ import annotations

from typing import Any

from unilab_jax import nets, nets_temporal
from unilab_jax import xp as shim
from unilab_jax.core import normalizer
from unilab_jax.core.normalizer import RunningStats


def teacher_dims(params: dict) -> tuple[int, int, int]:
    """(d frame features, p extrinsics, Z latent) of a teacher's parameters."""
    p = int(params["encoder"][0]["w"].shape[0])
    z = int(params["encoder"][-1]["w"].shape[1])
    return int(params["actor"][0]["w"].shape[0]) - z, p, z


def sub_stats(stats: RunningStats, start: int, stop: int) -> RunningStats:
    """Statistics of feature columns ``[start, stop)``."""
    return RunningStats(mean=stats.mean[start:stop], var=stats.var[start:stop], count=stats.count)


def frame_and_extrinsics_stats(obs_norm: RunningStats, d: int, p: int) -> tuple[RunningStats, RunningStats]:
    """The statistics of the last frame's and of the extrinsics' columns of an ``[H d | p]`` layout."""
    n = int(obs_norm.mean.shape[0])
    return sub_stats(obs_norm, n - p - d, n - p), sub_stats(obs_norm, n - p, n)


def latent(encoder: list, ext_normed: Any) -> Any:
    """``z = tanh(mlp(extrinsics))``: ext_normed [..., p] -> [..., Z]."""
    xp = shim.namespace(ext_normed)
    return xp.tanh(nets.apply(encoder, ext_normed))


def policy_mean(actor: list, frame_normed: Any, z: Any) -> Any:
    """The teacher's policy head on ``[current frame, z]`` -> action mean [..., A]."""
    xp = shim.namespace(frame_normed, z)
    return nets.apply(actor, xp.concat([frame_normed, z], axis=-1))


def teacher_actor(params: dict, obs_norm: RunningStats, obs: Any) -> tuple[Any, Any]:
    """PPO actor of the teacher (``ppo.Actor``): obs [..., H d + p] -> (mean, log_std) [..., A].

    Works for any history length H of the same frame layout (only the last frame is read).
    """
    xp = shim.namespace(obs)
    d, p, _ = teacher_dims(params)
    n = int(obs.shape[-1])
    frame_stats, ext_stats = frame_and_extrinsics_stats(obs_norm, d, p)
    frame = normalizer.normalize(frame_stats, obs[..., n - p - d:n - p])
    z = latent(params["encoder"], normalizer.normalize(ext_stats, obs[..., n - p:]))
    mean = policy_mean(params["actor"], frame, z)
    return mean, xp.broadcast_to(params["log_std"], mean.shape)


def history_stats(obs_norm: RunningStats, d: int, p: int, history_len: int) -> RunningStats:
    """Per-position statistics ``[H, d]`` for a student's history: the teacher's frame statistics tiled."""
    xp = shim.namespace(obs_norm.mean)
    frame, _ = frame_and_extrinsics_stats(obs_norm, d, p)
    tile = lambda a: xp.broadcast_to(xp.reshape(a, (1, d)), (history_len, d)) * 1.0  # a copy, not a view
    return RunningStats(mean=tile(frame.mean), var=tile(frame.var), count=obs_norm.count)


def student_latent(adapt: dict, history_norm: RunningStats, obs: Any) -> tuple[Any, Any]:
    """(z_hat [..., Z], normalised frames [..., H, d]) from the history part of obs [..., H d + p].

    Reads only the first ``H d`` columns: the extrinsics that follow are never an input.
    """
    xp = shim.namespace(obs)
    h, d = (int(s) for s in history_norm.mean.shape)
    frames = xp.reshape(obs[..., : h * d], (*obs.shape[:-1], h, d))
    x = normalizer.normalize(history_norm, frames)
    return xp.tanh(nets_temporal.adaptation_apply(adapt, x)), x


# ---------------------------------------------------------------------------------------------
# Flag and spec checks (both stages: JAX learners on a ``<task>_hist`` task)
# ---------------------------------------------------------------------------------------------
PLATFORMS = ("jax",)


def check_run(algo: str, platform: str, task_config: Any, task_needed: str) -> None:
    """``algo``'s flag checks before anything starts (``cli.build_run``): ValueError with the reason;
    ``task_needed`` says which task variant the stage needs (the message's tail)."""
    if platform not in PLATFORMS:
        raise ValueError(f"{algo} has a learner for --platform={'/'.join(PLATFORMS)} only, not {platform!r}")
    if not getattr(task_config, "history_extrinsics", False):
        raise ValueError(f"{algo} needs {task_needed}")


def check_spec(algo: str, spec: Any) -> None:
    if not getattr(spec, "extrinsics_in_obs", False):
        raise ValueError(f"{algo} needs a '<task>_hist' task with history_extrinsics=True, got {spec.name!r}")
