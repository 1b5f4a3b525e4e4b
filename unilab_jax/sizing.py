"""Machine-sized runs: how many rollout workers, and environments per worker, suit this machine.

``--num_workers=auto`` gives the workers every core the learner does not need; ``--envs_per_worker=auto``
splits the environments a recipe was tuned with (its :class:`SizedFor`) over those workers, so the
algorithm sees the same batch on any machine. Pure functions of the core count (tested as such); only
:func:`available_cores` asks the operating system and :func:`learner_on_cpu` the learner's array library.
"""

from __future__ import annotations

import dataclasses
import math
import os

AUTO = "auto"


@dataclasses.dataclass(frozen=True)
class SizedFor:
    """What a recipe was tuned on: ``num_workers`` x ``envs_per_worker`` on ``machine`` (words)."""

    machine: str
    num_workers: int
    envs_per_worker: int

    @property
    def total_envs(self) -> int:
        return self.num_workers * self.envs_per_worker

    def __str__(self) -> str:
        return f"{self.num_workers} workers x {self.envs_per_worker} envs on {self.machine}"


def available_cores() -> int:
    """CPU cores this process may run on: its affinity mask where the OS has one (containers, taskset),
    else ``os.cpu_count()``."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def learner_on_cpu(platform: str) -> bool:
    """Whether a ``platform`` ("jax" or "mlx") learner computes on the CPU: JAX's default backend, MLX's default
    device."""
    if platform == "jax":
        import jax

        return jax.default_backend() == "cpu"
    import mlx.core as mx

    return mx.default_device().type == mx.cpu


def learner_cores(cores: int, learner_on_cpu: bool) -> int:
    """Cores kept for the learner process: one for its loop when it feeds an accelerator; a quarter of the
    machine (at least one) when its own computation runs on the CPU too."""
    return max(1, cores // 4) if learner_on_cpu else 1


def auto_num_workers(cores: int, learner_on_cpu: bool) -> int:
    """Rollout workers for ``cores`` cores: the cores the learner does not need, at least one."""
    if cores < 1:
        raise ValueError(f"cores must be positive, got {cores}")
    return max(1, cores - learner_cores(cores, learner_on_cpu))


def auto_envs_per_worker(total_envs: int, num_workers: int) -> int:
    """``total_envs`` split over ``num_workers`` workers, rounded up (never fewer environments in all)."""
    if total_envs < 1 or num_workers < 1:
        raise ValueError(f"total_envs and num_workers must be positive, got {total_envs}, {num_workers}")
    return math.ceil(total_envs / num_workers)


def parse_count(text: str | int) -> int | str:
    """A flag value: ``auto`` or an integer (range checks come later, with the other flags)."""
    if isinstance(text, int) or text == AUTO:
        return text
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"expected an integer or {AUTO!r}, got {text!r}") from None
