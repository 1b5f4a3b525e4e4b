"""The pool's monitoring numbers, read from the workers' counters in the shared control block.

``PoolStats.read`` is what ``WorkerPool.stats()`` returns: env steps and rates, the episodes ended since the
previous call (returns, lengths, terminated fraction, the task's per-episode metrics), per-term reward means,
the workers' policy versions, pids, restarts and faults, and where their time goes. The workers write the
counters (``unilab_jax/runtime/worker.py``, ``control_layout``); this module only reads them.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from unilab_jax.runtime.buffers import ReplayBuffer
from unilab_jax.runtime.shm import SharedArrays
from unilab_jax.runtime.worker import (
    CHUNKS,
    EPISODES,
    INTERRUPTED,
    JAX,
    NONFINITE,
    PID,
    STEPS,
    TERM_ROWS,
    TIMING,
    VERSION,
    W_RETRIES,
    WAITING,
)


class PoolStats:
    """Rates and means since the previous ``read`` (the first one: since ``restart_clock``) from the control
    block ``control`` of a pool whose task has ``spec`` (its ``reward_terms`` and ``episode_metrics``)."""

    def __init__(self, control: SharedArrays, spec: Any) -> None:
        self._ctl, self.spec = control, spec
        self._t_start = time.monotonic()
        self._last_stats: tuple[float, int, np.ndarray, int, int] | None = None

    def restart_clock(self) -> None:
        """Rates count from now (the pool calls it once its workers have started)."""
        self._t_start = time.monotonic()

    def read(self, version: int, restarts: int, buffer: Any) -> dict[str, Any]:
        """The numbers of ``WorkerPool.stats()``; ``version``: the published weight version, ``restarts``:
        worker respawns so far, ``buffer``: the pool's buffer (replay buffers add their size)."""
        words = self._ctl["worker"].copy()
        now = time.monotonic()
        steps = int(words[:, STEPS].sum())
        term_sum = self._ctl["term_sum"].sum(axis=0)
        term_rows = int(words[:, TERM_ROWS].sum())
        episodes = int(words[:, EPISODES].sum())
        if self._last_stats is None:
            prev_t, prev_steps, prev_sum, prev_rows, prev_eps = self._t_start, 0, np.zeros_like(term_sum), 0, 0
        else:
            prev_t, prev_steps, prev_sum, prev_rows, prev_eps = self._last_stats
        self._last_stats = (now, steps, term_sum, term_rows, episodes)
        dt = max(now - prev_t, 1e-9)
        n_ep = np.minimum(words[:, EPISODES], self._ctl["ep_return"].shape[1])
        returns = np.concatenate([self._ctl["ep_return"][i, : n_ep[i]] for i in range(len(words))])
        lengths = np.concatenate([self._ctl["ep_length"][i, : n_ep[i]] for i in range(len(words))])
        terminated = np.concatenate([self._ctl["ep_terminated"][i, : n_ep[i]] for i in range(len(words))])
        rows = max(term_rows - prev_rows, 1)
        terms = {name: float((term_sum[i] - prev_sum[i]) / rows) for i, name in enumerate(self.spec.reward_terms)}
        n_terms, ended = len(self.spec.reward_terms), episodes - prev_eps
        # Per-episode task metrics (e.g. the intervention rate): means over the episodes ended since the last call.
        per_episode = {name: float((term_sum[n_terms + j] - prev_sum[n_terms + j]) / ended)
                       for j, name in enumerate(self.spec.episode_metrics) if ended > 0}
        retries = int(words[:, W_RETRIES].sum())
        out = {
            "env_steps": steps,
            "env_steps_per_s": (steps - prev_steps) / dt,
            "env_steps_per_s_total": steps / max(now - self._t_start, 1e-9),
            "episodes": episodes,
            "episode_metrics": per_episode,
            "episode_return_mean": float(returns.mean()) if returns.size else float("nan"),
            "episode_length_mean": float(lengths.mean()) if lengths.size else float("nan"),
            "episode_terminated_fraction": float(terminated.mean()) if terminated.size else float("nan"),
            "recent_episode_returns": returns,
            "recent_episode_lengths": lengths,
            "reward_terms": terms,
            "worker_policy_versions": words[:, VERSION].tolist(),
            "published_version": version,
            "weight_read_retries": retries,
            "chunks": int(words[:, CHUNKS].sum()),
            "worker_pids": words[:, PID].tolist(),
            "workers_with_jax": int(words[:, JAX].sum()),
            "worker_restarts": restarts,
            "nonfinite_rows": int(words[:, NONFINITE].sum()),
            "interrupted_steps": int(words[:, INTERRUPTED].sum()),
            "workers_waiting": int(words[:, WAITING].sum()),  # inside a task step, e.g. for a lost robot
        }
        timing = self._ctl["timing"].sum(axis=0)
        total = max(float(timing.sum()), 1e-9)
        out["worker_time_fraction"] = {name: float(timing[i] / total) for i, name in enumerate(TIMING)}
        out["worker_wait_s"] = float(timing[TIMING.index("wait")])  # summed over workers, since the start
        if isinstance(buffer, ReplayBuffer):
            out["replay_size"] = buffer.size()
            out["replay_resampled"] = buffer.resampled
        return out
