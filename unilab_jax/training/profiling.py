"""An in-run trace of the training loop: ``--profile_dir`` (``RunConfig.profile_dir``).

``ProfileWindow(run)`` starts ``jax.profiler`` (device kernels, XLA's host threads and every Python thread of the
learner process: the loop, the learner, prefetch and evaluation threads) when the loop reaches update
``profile_start`` and stops it ``profile_updates`` updates later, so the trace holds steady-state calls only
(no compile, no warm-up). The trace (TensorBoard/XProf files and a Perfetto JSON) goes under ``profile_dir``;
``bench/trace_summary.py`` summarises its kernels, ``--threads`` its Python threads.
"""

from __future__ import annotations

import logging
from typing import Any

log = logging.getLogger(__name__)


class ProfileWindow:
    """Traces updates ``[profile_start, profile_start + profile_updates)`` of a run with a JAX learner."""

    def __init__(self, run: Any):
        self.dir, self.start, self.stop_at = run.profile_dir, run.profile_start, run.profile_start + run.profile_updates
        self.active = False
        self.done = not run.profile_dir or run.platform != "jax"

    def step(self, updates: int) -> None:
        """Called before each update with the number of updates made so far."""
        if self.done:
            return
        import jax

        if not self.active and updates >= self.start:
            log.info("tracing updates %d-%d into %s", updates, self.stop_at - 1, self.dir)
            jax.profiler.start_trace(self.dir, create_perfetto_trace=True)
            self.active = True
        elif self.active and updates >= self.stop_at:
            self.close()

    def close(self) -> None:
        """Stops a trace in progress (also at the end of a run that stops inside the window)."""
        if self.active:
            import jax

            jax.profiler.stop_trace()
            log.info("trace written under %s", self.dir)
        self.active, self.done = False, True
