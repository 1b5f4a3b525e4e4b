"""One host's rollouts for a learner elsewhere: the host's :class:`WorkerPool` (replay) and a pull interface.

:class:`~unilab_jax.runtime.ray_pool.RayPool` runs one of these per Ray node, as an actor pinned to that node;
the class itself knows nothing of Ray (the shared-memory runtime inside the host is unchanged). Calls run one
at a time, in the order the learner sent them:

* ``start()`` starts the host's worker processes and waits until each has built its task;
* ``publish(weights, version)`` hands a weight version to the host's workers;
* ``allow(limit)`` sets the host pool's env-step limit (the learner's share of the run's budget for it);
* ``pull(min_rows, max_wait_s)`` waits until the workers committed ``min_rows`` new transitions (or
  ``max_wait_s`` passed) and returns them as one batch of numpy arrays (shipped through Ray's object store):
  per worker the global row index of its first row and the count, the rows worker after worker, the
  number of the pull (``seq``, 1, 2, ...) and the pool's statistics. Rows are read with the ring's lock-free
  protocol (:meth:`ReplayBuffer.read_new`); rows the host's ring overwrote before a pull reached them
  (a learner that stopped pulling for a whole ring) are skipped and counted in ``overrun``, never sent torn.

A dead worker inside the host is handled by the host's pool as in a local run (respawned, or its Python
error raised by the next ``pull``).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from unilab_jax.runtime.pool import WorkerPool

STAT_KEYS = ("env_steps", "episodes", "episode_terminated_fraction", "worker_restarts", "nonfinite_rows",
             "interrupted_steps", "workers_waiting", "worker_wait_s", "recent_episode_returns",
             "recent_episode_lengths", "reward_terms", "worker_time_fraction")


class HostRollouts:
    """A replay :class:`WorkerPool` on this host, read by pulls (see the module docstring)."""

    def __init__(self, **pool_kwargs: Any):
        self.pool = WorkerPool(**pool_kwargs)
        if self.pool.buffer_kind != "replay":
            self.pool.close()
            raise ValueError("host rollouts carry replay transitions (off-policy algorithms)")
        self._synced = np.zeros(self.pool.num_workers, np.int64)
        self._seq = 0
        self.fields = tuple(self.pool.fields)

    def start(self, timeout: float = 300.0) -> int:
        """Starts the workers; returns their number once each has built its task."""
        self.pool.start(timeout=timeout)
        return self.pool.num_workers

    def publish(self, weights: Any, version: int) -> None:
        if version > self.pool.version:
            self.pool.publish(weights, version)

    def allow(self, limit: int) -> None:
        self.pool.set_step_limit(limit)

    def pull(self, min_rows: int, max_wait_s: float) -> dict[str, Any]:
        buf = self.pool.buffer
        deadline = time.monotonic() + max_wait_s
        while True:
            self.pool._maybe_check_workers()
            if int(np.sum(buf._count[:, 0] - self._synced)) >= min_rows or time.monotonic() >= deadline:
                break
            time.sleep(0.005)
        new = buf.read_new(self._synced, self.fields)
        cap, w = buf.capacity, buf.num_workers
        hi, lo = new["hi"], new["lo"]
        n = np.bincount(new["slots"] // cap, minlength=w).astype(np.int64)
        first = hi - n  # global row of each worker's first row copied
        worker = np.repeat(np.arange(w), n)
        g = np.repeat(first, n) + np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        keep = g >= lo[worker]  # rows the writer may have reached during the copy are not sent
        start = np.maximum(first, np.minimum(lo, hi))
        overrun = int(np.sum(start - self._synced))
        self._synced = hi.copy()
        self._seq += 1
        stats = self.pool.stats()
        return {"seq": self._seq, "start": start, "n": hi - start, "overrun": overrun,
                "rows": {k: v[keep] for k, v in new["rows"].items()},
                "stats": {k: stats[k] for k in STAT_KEYS}}

    def close(self) -> None:
        self.pool.close()
