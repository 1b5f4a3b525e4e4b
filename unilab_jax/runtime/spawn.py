"""Starting and stopping the rollout worker processes: what ``WorkerPool`` does around ``Process.start`` and at
close.

Worker processes use the ``spawn`` context. While they are started (``hidden_main``), the learner's
``__main__`` module is hidden from multiprocessing so the children do not re-import the training script
(which would import jax into every worker and slow its start); workers import only the runtime, the task
and the algorithm module. ``worker_environment`` pins the BLAS / OpenMP thread pools the children inherit,
and ``cpu_placement`` computes each worker's CPU set when the learner keeps some cores to itself.
``PoolResources`` holds what must be released at close: it raises the shared stop flag, joins the workers
(SIGKILL after a grace period) and closes every segment; ``WorkerPool`` runs it from ``close()`` and from a
``weakref.finalize`` at exit, and its first half alone from ``stop()``.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from unilab_jax.runtime.shm import SharedArrays
from unilab_jax.runtime.worker import STOP_FLAG


@contextlib.contextmanager
def hidden_main() -> Iterator[None]:
    """Keeps spawn from re-running the learner's main script in the workers."""
    main = sys.modules.get("__main__")
    saved = {}
    if main is not None:
        for attr in ("__file__", "__spec__"):
            if hasattr(main, attr):
                saved[attr] = getattr(main, attr)
        if "__file__" in saved:
            del main.__file__
        main.__spec__ = None
    try:
        yield
    finally:
        if main is not None:
            for attr, value in saved.items():
                setattr(main, attr, value)
            if "__spec__" not in saved:
                with contextlib.suppress(AttributeError):
                    del main.__spec__


THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
               "NUMEXPR_NUM_THREADS", "BLIS_NUM_THREADS")


@contextlib.contextmanager
def worker_environment(threads: int) -> Iterator[None]:
    """Spawned workers inherit the environment: pin their BLAS / OpenMP pools to ``threads``.

    A worker's policy matmuls are tiny ([M, 48] x [48, 512] ...); a BLAS pool of one thread per core
    in each of W workers oversubscribes the CPU and made inference ~20x slower in measurements here.
    """
    saved = {k: os.environ.get(k) for k in THREAD_VARS}
    os.environ.update({k: str(threads) for k in THREAD_VARS})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def cpu_placement(num_workers: int, learner_cores: int, cpus: Sequence[int] | None = None) -> list[list[int]]:
    """Each worker's CPU set when the first ``learner_cores`` usable CPUs (``cpus``, default this process's
    affinity) are left free for the learner process: the other CPUs are split into ``num_workers``
    contiguous shares (one CPU each, shared round-robin, when there are more workers than CPUs)."""
    cpus = sorted(os.sched_getaffinity(0) if cpus is None else cpus)
    if not 0 <= learner_cores < len(cpus):
        raise ValueError(f"learner_cores={learner_cores}: must leave at least one of the {len(cpus)} usable CPUs "
                         "to the workers")
    rest = cpus[learner_cores:]
    if num_workers > len(rest):
        return [[rest[i % len(rest)]] for i in range(num_workers)]
    return [[int(c) for c in share] for share in np.array_split(rest, num_workers)]


class PoolResources:
    """What must be released at close: processes and segments (referenced by the finalizer). ``stop`` ends the
    processes alone (the segments can still be read); ``shutdown`` ends them if needed and closes every segment."""

    def __init__(self) -> None:
        self.procs: list[Any] = []
        self.closers: list[Any] = []  # objects with close(), closed in reverse order
        self.control: SharedArrays | None = None
        self.stopped = False
        self.closed = False

    def shutdown(self, grace: float = 5.0) -> None:
        if self.closed:
            return
        self.closed = True
        self.stop(grace)
        for obj in reversed(self.closers):
            with contextlib.suppress(Exception):
                obj.close()

    def stop(self, grace: float = 5.0) -> None:
        """Raises the shared stop flag and joins the workers, SIGKILLed past ``grace`` seconds."""
        if self.stopped:
            return
        self.stopped = True
        if self.control is not None:
            with contextlib.suppress(Exception):
                self.control["flags"][STOP_FLAG] = 1
        deadline = time.monotonic() + grace
        for p in self.procs:
            p.join(max(0.0, deadline - time.monotonic()))
        for p in self.procs:  # workers ignore SIGTERM (see worker_main): past the grace period, SIGKILL
            if p.is_alive():
                p.kill()
                p.join(2.0)
