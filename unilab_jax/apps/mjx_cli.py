"""Flags of the MJX experiments (``experiments/*_mjx.py``), validated before anything compiles.

The shared experiment flags of ``unilab_jax.apps.cli`` (``--total_steps``, ``--seed``, ``--logdir``,
``--eval_every``, ``--eval_envs``, ``--config``, ``--task_config``, ``--task``) plus ``--num_envs``,
``--max_seconds`` and ``--iterations_per_call``; the worker flags of the heterogeneous runtime are rejected::

    from unilab_jax.apps.mjx_cli import run_mjx_experiment
    run_mjx_experiment(algo="ppo", task="go1_joystick_flat", recipe={...}, default_num_envs=8192)
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

from absl import flags

from unilab_jax.apps import cli
from unilab_jax.training import compile_cache

FLAGS = flags.FLAGS
flags.DEFINE_integer("num_envs", None, "MJX environments stepped together on the accelerator (default: the "
                     "experiment's)")
flags.DEFINE_float("max_seconds", 0.0, "stop after this much wall time from process start (0: no limit)")
flags.DEFINE_integer("iterations_per_call", None, "training iterations per jitted call, one logged row per call "
                     "(default: the experiment's)")

RUNTIME_ONLY = ("num_workers", "envs_per_worker", "serial", "resume", "checkpoint_every", "replay_dir", "ray_address",
                "ray_workers_per_host")


def build_run(algo: str, task: str, recipe: Mapping[str, Any], task_recipe: Mapping[str, Any],
              default_total_steps: int, default_num_envs: int,
              default_iterations_per_call: int) -> tuple[Any, Any, Any, dict[str, Any]]:
    """Validates the flags; returns (MjxRunConfig, algorithm module, algorithm config, task overrides)."""
    import tasks
    from unilab_jax import algos
    from unilab_jax.config import apply_overrides, parse_overrides
    from unilab_jax.training.mjx import MJX_TASKS, MjxRunConfig

    given = [name for name in RUNTIME_ONLY if name in FLAGS and FLAGS[name].present]
    if given:
        raise cli.FlagError(f"--{given[0]} is a flag of the CPU-worker runtime; MJX runs take --num_envs")
    if FLAGS.wandb_project:
        raise cli.FlagError("--wandb_project: the MJX loop logs to TensorBoard and metrics.jsonl only")
    if FLAGS.platform != "jax":
        raise cli.FlagError(f"--platform={FLAGS.platform!r}: MJX runs need jax")
    if FLAGS.devices != "1":
        raise cli.FlagError(f"--devices={FLAGS.devices}: MJX runs train on one device")
    task_name = FLAGS.task or task
    if task_name not in MJX_TASKS:
        raise cli.FlagError(f"--task={task_name!r}: tasks with an MJX variant are {sorted(MJX_TASKS)}")
    num_envs = FLAGS.num_envs if FLAGS.num_envs is not None else default_num_envs
    iters = FLAGS.iterations_per_call if FLAGS.iterations_per_call is not None else default_iterations_per_call
    total = FLAGS.total_steps if FLAGS.total_steps is not None else default_total_steps
    for name, value in (("num_envs", num_envs), ("eval_envs", FLAGS.eval_envs), ("iterations_per_call", iters),
                        ("total_steps", total)):
        if value < 1:
            raise cli.FlagError(f"--{name} must be at least 1, got {value}")
    if FLAGS.eval_every < 0 or FLAGS.max_seconds < 0:
        raise cli.FlagError("--eval_every and --max_seconds must be >= 0")
    try:
        compile_cache.check(FLAGS.compilation_cache, "--compilation_cache")
    except ValueError as e:
        raise cli.FlagError(str(e)) from None
    module = algos.get(algo)
    config = apply_overrides(apply_overrides(module.Config(), dict(recipe)), parse_overrides(FLAGS.config))
    task_overrides = {**dict(task_recipe if task_name == task else {}), **parse_overrides(FLAGS.task_config)}
    task_config = apply_overrides(tasks.default_config(task_name), task_overrides)  # rejects unknown keys
    task_overrides = {k: getattr(task_config, k) for k in task_overrides}
    if module.BUFFER == "trajectory" and config.horizon * num_envs < config.num_minibatches:
        raise cli.FlagError(f"a batch of {config.horizon * num_envs} transitions cannot make "
                            f"{config.num_minibatches} minibatches")
    logdir = FLAGS.logdir or os.path.join("runs", f"{algo}_mjx_{task_name}_s{FLAGS.seed}")
    try:
        os.makedirs(logdir, exist_ok=True)
    except OSError as e:
        raise cli.FlagError(f"--logdir={logdir!r} cannot be created: {e}") from e
    run = MjxRunConfig(algo=algo, task=task_name, num_envs=num_envs, total_steps=total, seed=FLAGS.seed,
                       logdir=logdir, eval_every=FLAGS.eval_every, eval_envs=FLAGS.eval_envs,
                       max_seconds=FLAGS.max_seconds, iterations_per_call=iters,
                       compilation_cache=FLAGS.compilation_cache)
    return run, module, config, task_overrides


def run_mjx_experiment(algo: str, task: str, recipe: Mapping[str, Any] | None = None,
                       task_recipe: Mapping[str, Any] | None = None, default_total_steps: int = 100_000_000,
                       default_num_envs: int = 8192, default_iterations_per_call: int = 1) -> None:
    """Parses the flags, validates them, trains on MJX, prints the summary."""

    def validate() -> Any:
        run, module, config, task_overrides = build_run(algo, task, recipe or {}, task_recipe or {},
                                                        default_total_steps, default_num_envs,
                                                        default_iterations_per_call)
        from unilab_jax.training.mjx import make_trainer

        return make_trainer(run, module, config, task_overrides, start_time=cli.PROCESS_START)

    def train(trainer: Any) -> None:
        cli.report(trainer.train())

    names = ["platform", "task", "total_steps", "seed", "logdir", "eval_every", "eval_envs", "devices", "config",
             "task_config", "num_envs", "iterations_per_call", "max_seconds"]
    cli.launch(validate, train, errors=(ValueError,), help=lambda: cli.help_text(
        algo, task, recipe or {}, task_recipe or {}, default_total_steps, flag_names=names,
        defaults={"num_envs": default_num_envs, "iterations_per_call": default_iterations_per_call}))
