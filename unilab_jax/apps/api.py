"""Training from Python: ``unilab_jax.train`` (this module's :func:`train`), validated as the command line is.

    import unilab_jax
    summary = unilab_jax.train("ppo", "cartpole_balance", logdir="runs/ppo_cartpole", total_steps=200_000,
                               config={"horizon": 32}, num_workers=2, envs_per_worker=32)

    from unilab_jax import recipes
    r = recipes.get("ppo_cartpole")  # what experiments/ppo_cartpole.py runs
    summary = unilab_jax.train(r.algo, r.task, logdir="runs/ppo_cartpole", total_steps=r.total_steps,
                               config=r.recipe, task_config=r.task_recipe)

Every argument goes through ``apps.cli.build_run``, the experiments' own checks: an unknown algorithm, task,
config key or run option, a value of the wrong type or out of range raises ``ValueError`` (``ConfigError`` for
config keys and values, a subclass) before any worker starts or any file is written but the log directory.
"""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Mapping
from typing import Any

from unilab_jax import sizing
from unilab_jax.apps import cli
from unilab_jax.training.trainer import RunConfig, Trainer

# train()'s run options: RunConfig's fields, each set on the command line by the apps/cli.py flag of its name (the
# algorithm, task, step budget and log directory are train()'s own arguments).
RUN_OPTIONS = tuple(f.name for f in dataclasses.fields(RunConfig) if f.name not in ("algo", "task", "total_steps",
                                                                                     "logdir"))


def options(algo: str, task: str, *, logdir: str, total_steps: int, config: Mapping[str, Any] | None = None,
            task_config: Mapping[str, Any] | None = None, **run_options: Any) -> types.SimpleNamespace:
    """The flags' namespace ``build_run`` reads, from ``train``'s arguments (the flags' defaults elsewhere)."""
    unknown = sorted(set(run_options) - set(RUN_OPTIONS))
    if unknown:
        raise ValueError(f"unknown run option(s) {unknown}; valid: {sorted(RUN_OPTIONS)} (algorithm "
                         "hyperparameters go in config=, task parameters in task_config=)")
    for name, value in (("config", config), ("task_config", task_config)):
        if value is not None and not isinstance(value, Mapping):
            raise ValueError(f"{name} must be a dict of field -> value, got {type(value).__name__}")
    if not isinstance(total_steps, int) or isinstance(total_steps, bool):
        raise ValueError(f"total_steps must be an integer, got {total_steps!r}")
    if not logdir:
        raise ValueError("logdir must name a directory")
    values = {name: cli.FLAGS[name].default for name in RUN_OPTIONS}
    values.update(run_options)
    if isinstance(values["devices"], int) and not isinstance(values["devices"], bool):
        values["devices"] = str(values["devices"])
    for name in ("num_workers", "envs_per_worker"):
        values[name] = sizing.parse_count(values[name]) if isinstance(values[name], str) else values[name]
    for name in RUN_OPTIONS:
        default = cli.FLAGS[name].default
        value = values[name]
        ok = (isinstance(value, type(default)) and not (isinstance(value, bool) and not isinstance(default, bool))
              or (isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool))
              or (name in ("num_workers", "envs_per_worker") and value == sizing.AUTO))
        if not ok:
            raise ValueError(f"run option {name}={value!r}: expected {type(default).__name__}")
    return types.SimpleNamespace(**values, task=task, total_steps=total_steps, logdir=logdir,
                                 config=dict(config or {}), task_config=dict(task_config or {}),
                                 given=set(run_options))


def build(algo: str, task: str, **kwargs: Any) -> tuple[Any, Any, Any, dict[str, Any]]:
    """``train``'s arguments validated: (RunConfig, algorithm module, algorithm config, task overrides).
    Raises ``ValueError`` (``ConfigError`` for config keys and values) on any bad argument."""
    opts = options(algo, task, **kwargs)
    return cli.build_run(algo, task, {}, {}, opts.total_steps, opts=opts)


def train(algo: str, task: str, *, logdir: str, total_steps: int, config: Mapping[str, Any] | None = None,
          task_config: Mapping[str, Any] | None = None, **run_options: Any) -> dict[str, Any]:
    """Trains ``algo`` (a registered algorithm: ``unilab_jax.algos.names()``) on ``task`` (``tasks.names()`` or
    ``gym:ENV_ID``) for ``total_steps`` env steps, logging to ``logdir`` (TensorBoard events, ``metrics.jsonl``,
    checkpoints, ``summary.json``). ``config``: algorithm hyperparameters (fields of ``algos.get(algo).Config``);
    ``task_config``: task parameters (fields of ``tasks.default_config(task)``); ``run_options``: the command
    line's run flags by name (``num_workers``, ``envs_per_worker``, ``seed``, ``eval_every``, ``resume``, ...:
    ``RUN_OPTIONS``). Returns the run's summary (``env_steps``, ``updates``, ``eval/return`` ..., and ``warning``
    when the run made no learner update or fewer than asked)."""
    parts = build(algo, task, logdir=logdir, total_steps=total_steps, config=config, task_config=task_config,
                  **run_options)
    return Trainer(*parts).train()
