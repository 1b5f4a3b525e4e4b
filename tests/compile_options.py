"""XLA options for programs that the tests compile only to check them, not to time them or to train far:
LLVM at -O0 and XLA's classic CPU emitters instead of its fusion emitters.

``FAST_COMPILE`` is for ``jax.jit``'s ``compiler_options`` (the learners and MJX trainers take it too).
CPU seconds of a whole file, LLVM -O0 alone -> both options: tests/test_mjx_training.py 113 -> 71,
tests/tasks/test_mjx_walking_parity.py 90 -> 59, tests/algos/test_compute_dtype.py 29 -> 15 (the Go1 MJX step
compiles in 14 instead of 23); every parity tolerance holds unchanged.

``fast_compile_env()`` is the environment for a subprocess, where XLA reads them from ``XLA_FLAGS``: experiment
scripts run on budgets of a few updates to check their plumbing (logs, checkpoints, resume, export), whose time is
nearly all compilation. CPU seconds with XLA's defaults -> these flags (2-core VM):
tests/test_hora_him_experiments.py 43 -> 17, tests/test_allegro_experiments.py 23 -> 11, tests/test_play_export.py
43 -> 31, tests/test_sharding.py (its script) 33 -> 14. Not for learning runs: at -O0 their updates run slower than
the compile saves (tests/test_experiments.py's two 20k-step PPO Go1 runs: 18 -> 22 s).
"""

from __future__ import annotations

import os

import jax

# XLA's CPU options: a GPU compile refuses them ("No such compile option"), so the tests that also run on the GPU
# machine (tests/algos/test_compute_dtype.py's Pallas checks) compile there with XLA's defaults.
FAST_COMPILE = ({"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}
                if jax.default_backend() == "cpu" else {})
FAST_COMPILE_FLAGS = "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false"


def fast_compile_env(base: dict[str, str] | None = None) -> dict[str, str]:
    """``base`` (default ``os.environ``) with ``FAST_COMPILE_FLAGS`` added to its ``XLA_FLAGS``."""
    env = dict(os.environ if base is None else base)
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {FAST_COMPILE_FLAGS}".strip()
    return env
