"""Machine-sized runs: how many rollout workers, and environments per worker, suit this machine.

``--num_workers=auto`` gives the workers every core the learner does not need, and ``--pin_cpus=auto`` keeps them
off the learner's cores when it feeds an accelerator; ``--envs_per_worker=auto``
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
    """Cores kept for the learner process. Feeding an accelerator: three on a machine of 12 cores or more (its busy
    host threads: the update's dispatch, the loop that fetches and publishes, the replay prefetch), else one; a
    quarter of the machine (at least one) when its own computation runs on the CPU too. Measured (FastSAC Go1, H100
    + 16 cores, docs/perf/learner_scaling.md section 8): 13 workers kept off 3 cores made 55-58 learner calls/s and
    walked at 106-125 s; 15 workers sharing every core, 30-32 calls/s, 139-142 s or not by 160 s."""
    if learner_on_cpu:
        return max(1, cores // 4)
    return 3 if cores >= 12 else 1


def auto_num_workers(cores: int, learner_on_cpu: bool) -> int:
    """Rollout workers for ``cores`` cores: the cores the learner does not need, at least one."""
    if cores < 1:
        raise ValueError(f"cores must be positive, got {cores}")
    return max(1, cores - learner_cores(cores, learner_on_cpu))


def auto_pin_cpus(cores: int, num_workers: int, learner_on_cpu: bool) -> int:
    """``--pin_cpus=auto``: with a learner on an accelerator, the workers kept off the learner's cores
    (:func:`learner_cores`) when each still gets a core of its own; otherwise -1 (no affinity). A learner on the CPU
    computes with every core (XLA's threads), so its workers are not confined."""
    if learner_on_cpu:
        return -1
    keep = learner_cores(cores, learner_on_cpu)
    return keep if 1 <= num_workers <= cores - keep else -1


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
