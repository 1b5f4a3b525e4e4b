"""UniLab-JAX: heterogeneous robot RL (CPU MuJoCo workers, shared memory, JAX/MLX learners).

Importing this package imports numpy only; the JAX backend loads when asked for. ``unilab_jax.train`` trains
from Python (``unilab_jax/apps/api.py``, imported when called); ``unilab_jax.recipes`` holds the experiments'
recipes as data.
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"


def train(algo: str, task: str, *, logdir: str, total_steps: int, config: dict[str, Any] | None = None,
          task_config: dict[str, Any] | None = None, **run_options: Any) -> dict[str, Any]:
    """Trains ``algo`` on ``task`` for ``total_steps`` env steps, logging to ``logdir``; returns the run's summary.
    Validated as the command line is (``ValueError`` before anything starts); see ``unilab_jax.apps.api.train``."""
    from unilab_jax.lazy import load  # the training wing lies above this package's layer: loaded by name

    return load("unilab_jax.apps.api:train")(algo, task, logdir=logdir, total_steps=total_steps, config=config,
                                             task_config=task_config, **run_options)


def __getattr__(name: str) -> Any:
    """``unilab_jax.recipes`` without importing it first (it is pure data)."""
    if name == "recipes":
        import importlib

        return importlib.import_module("unilab_jax.recipes")
    raise AttributeError(f"module 'unilab_jax' has no attribute {name!r}")
