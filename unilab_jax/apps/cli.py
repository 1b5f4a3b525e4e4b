"""The experiments' command line: the flags shared by every experiment script, validated before any worker
starts, and ``run_experiment``, which builds the run from them and trains it (``training/trainer.py``).
The family CLIs (``hora_cli``, ``mjx_cli``, ``robot_cli``) build on these flags and on ``launch``.

An experiment is a few lines::

    from unilab_jax.apps.cli import run_experiment
    run_experiment(algo="ppo", task="go1_joystick_flat", recipe={"horizon": 24},
                   sized_for=SizedFor("16-core H100 host", 16, 64))

Generic overrides: ``--config key=value`` (algorithm hyperparameters) and ``--task_config key=value``
(task parameters), repeatable; unknown keys are rejected with the list of valid ones.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections.abc import Callable, Mapping
from typing import Any

from absl import app, flags
from absl import logging as absl_logging

from unilab_jax import sizing
from unilab_jax.training import compile_cache

# The learner's numpy work is small (statistics, evaluation); OpenBLAS threads spinning on it would
# steal cores from the rollout workers. Set before numpy is first imported (nothing above imports it);
# the user's own value wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
# XLA's Triton GEMM autotuning made the first compile of the FastSAC update (batch 8192, 1024-wide C51
# critics, 8 scanned gradient steps) exceed 150 s on an H100; with cuBLAS GEMMs it compiled in 40 s
# (measured while another training run shared the machine; bench/results/README.md). CPU XLA accepts
# and ignores the flag; the user's own setting of it wins.
if "xla_gpu_enable_triton_gemm" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_gpu_enable_triton_gemm=false").strip()

PLATFORMS = ("jax", "mlx")
PROCESS_START = time.time()  # time-to-target clocks count from here (imports of jax etc. included)

# What a recipe without its own sizing was tuned on: the flag defaults, 2 workers x 32 envs.
DEV_VM = sizing.SizedFor("the 2-core dev VM", 2, 32)


class _CountOrAuto(flags.ArgumentParser):
    """An integer or ``auto`` (unilab_jax/sizing.py); anything else fails flag parsing."""

    syntactic_help = "an integer or 'auto'"

    def parse(self, argument: str | int) -> int | str:
        return sizing.parse_count(argument)

    def flag_type(self) -> str:
        return "int or auto"


FLAGS = flags.FLAGS
flags.DEFINE_string("platform", "jax", f"learner platform, one of {PLATFORMS}")
flags.DEFINE_string("task", None, "registered task name, or gym:ENV_ID for a Gymnasium environment with Box spaces "
                    "(default: the experiment's task)")
flags.DEFINE(_CountOrAuto(), "num_workers", DEV_VM.num_workers, "rollout worker processes; auto: the cores the "
             "learner does not need (the default of recipes sized for a machine)")
flags.DEFINE(_CountOrAuto(), "envs_per_worker", DEV_VM.envs_per_worker, "MuJoCo environments stepped by each "
             "worker; auto (the default with --num_workers=auto): the recipe's environments split over the workers")
flags.DEFINE_integer("total_steps", None, "environment steps to train for (default: the experiment's)")
flags.DEFINE_integer("seed", 0, "random seed")
flags.DEFINE_string("logdir", None, "where TensorBoard events, metrics.jsonl and checkpoints go")
flags.DEFINE_bool("resume", False, "continue the run saved in --logdir")
flags.DEFINE_integer("eval_every", 0, "env steps between deterministic evaluations (0: at the end only)")
flags.DEFINE_integer("eval_envs", 16, "environments in each evaluation")
flags.DEFINE_integer("checkpoint_every", 0, "env steps between checkpoints (0: at evaluations and the end)")
flags.DEFINE_integer("video_every", 0, "env steps between clips of an evaluation episode: mp4 under <logdir>/videos "
                     "and a frame strip in TensorBoard (0: none; headless Linux renders through EGL)")
flags.DEFINE_bool("serial", False, "run the workers in the learner process (debugging)")
flags.DEFINE_string("replay_dir", "", "off-policy: persistent replay store folder (write-through to disk, reopened "
                    "by --resume; empty: shared memory only)")
flags.DEFINE_float("replay_disk_gb", 10.0, "disk budget of --replay_dir; the oldest chunks are deleted past it")
flags.DEFINE_float("replay_hot_fraction", 0.5, "with --replay_dir: share of each minibatch drawn from shared memory")
flags.DEFINE_integer("replay_chunk_rows", 0, "with --replay_dir: transitions per committed chunk (0: ~16 MiB)")
flags.DEFINE_bool("keep_replay", False, "off-policy: at an orderly stop (the end, Ctrl-C, SIGTERM) write the replay "
                  "rings to <logdir>/replay_rings, which --resume copies back (not with --replay_dir or --ray_address)")
flags.DEFINE_enum("replay_on_device", "auto", ["auto", "on", "off"], "off-policy, jax learner: keep a copy of the "
                  "replay rings in accelerator memory and sample minibatches there (auto: on unless JAX runs on the "
                  "CPU or --replay_dir is set)")
flags.DEFINE_enum("eval_process", "auto", ["auto", "on", "off"], "run the evaluations' episodes in a process of "
                  "their own, off the learner process (auto: when the learner runs on an accelerator and not --serial)")
flags.DEFINE_enum("precompile", "auto", ["auto", "on", "off"], "off-policy, jax learner: compile the "
                  "update while the workers fill the replay rings, not at the first update (auto: when the learner "
                  "runs on an accelerator)")
flags.DEFINE_enum("utd_mode", "hold", ["hold", "free"], "off-policy: hold pauses the workers when the learner falls "
                  "more than --utd_window env steps behind the recipe's update-to-data ratio; free never pauses them")
flags.DEFINE_integer("utd_window", 0, "with --utd_mode=hold: env steps the workers may run ahead of the ratio "
                     "(0: four learner calls' worth)")
flags.DEFINE(_CountOrAuto(), "pin_cpus", sizing.AUTO, "worker CPU affinity: -1 none; K >= 0: each worker pinned to "
             "its share of the usable cores except the first K, which stay free for the learner process; auto: the "
             "learner's cores kept free when it runs on an accelerator and the workers fit on the others")
flags.DEFINE_string("devices", "1", "JAX learner: local accelerators to train on data-parallel, 'all' or a number "
                    "(the batch is split across them, parameters replicated; 1: the single-device path)")
flags.DEFINE_enum("device_split", "batch", ["batch", "critics"], "with --devices > 1: split each minibatch over "
                  "the devices (batch) or an off-policy learner's critic ensemble, each device holding some of its "
                  "critics (critics)")
flags.DEFINE_string("ray_address", "", "off-policy: run rollout workers on every node of this Ray cluster, 'auto' or "
                    "HOST:PORT of its head (empty: this host only; Ray is not imported)")
flags.DEFINE_integer("ray_workers_per_host", 0, "with --ray_address: worker processes on each node other than the "
                     "learner's (0: --num_workers)")
flags.DEFINE_string("wandb_project", "", "also log to this Weights & Biases project (pip install "
                    "'unilab-jax[wandb]'; WANDB_MODE=offline keeps the run under <logdir>/wandb; empty: no W&B)")
flags.DEFINE_string("profile_dir", "", "JAX learner: write a jax.profiler trace (kernels and Python threads) of "
                    "--profile_updates updates from update --profile_start into this folder")
flags.DEFINE_integer("profile_start", 300, "with --profile_dir: the update the trace starts at (past compile)")
flags.DEFINE_integer("profile_updates", 30, "with --profile_dir: how many updates the trace holds")
flags.DEFINE_string("compilation_cache", "auto", "jax learner: keep compiled programs in this folder so that a later "
                    "run with the same shapes loads them instead of compiling; auto: ~/.cache/unilab_jax/xla when the "
                    "learner runs on an accelerator, off on the CPU; off: never (JAX_COMPILATION_CACHE_DIR wins)")
flags.DEFINE_multi_string("config", [], "algorithm override key=value (repeatable)")
flags.DEFINE_multi_string("task_config", [], "task override key=value (repeatable)")


# The flags every run reads, and those only off-policy runs read (--help lists each script's own).
RUN_FLAGS = ("platform", "task", "total_steps", "num_workers", "envs_per_worker", "seed", "logdir", "resume",
             "eval_every", "eval_envs", "eval_process", "checkpoint_every", "video_every", "serial", "pin_cpus",
             "devices", "wandb_project", "profile_dir", "profile_start", "profile_updates", "compilation_cache",
             "config", "task_config")
REPLAY_FLAGS = ("replay_dir", "replay_disk_gb", "replay_hot_fraction", "replay_chunk_rows", "keep_replay",
                "replay_on_device", "precompile", "device_split", "utd_mode", "utd_window", "ray_address",
                "ray_workers_per_host")


def run_flags(algo: str) -> list[str]:
    """The shared flags a run of ``algo`` reads: the replay flags only for an off-policy algorithm."""
    from unilab_jax import algos

    return [*RUN_FLAGS, *(REPLAY_FLAGS if algos.get(algo).BUFFER == "replay" else ())]


def help_text(algo: str, task: str, recipe: Mapping[str, Any], task_recipe: Mapping[str, Any],
              default_total_steps: int, flag_names: list[str] | None = None, extra_flags: tuple[str, ...] = (),
              defaults: Mapping[str, Any] | None = None) -> str:
    """An experiment's ``--help``: its docstring, the run's flags, the algorithm's and the task's config fields."""
    from unilab_jax.apps import cli_help

    task_name = cli_help.requested_task(task)
    names = [*(run_flags(algo) if flag_names is None else flag_names), *extra_flags]
    return cli_help.text(cli_help.main_doc(), [
        cli_help.flag_lines("flags", names, {"task": task, "total_steps": default_total_steps, **(defaults or {})}),
        cli_help.algorithm_lines(algo, recipe),
        cli_help.task_lines(task_name, task_recipe if task_name == task else {})])


class FlagError(ValueError):
    """A bad flag value, reported before anything starts."""


def _given(opts: Any, name: str) -> bool:
    """Whether option ``name`` was set by the user (a flag on the command line, a keyword of ``train``)."""
    return FLAGS[name].present if opts is FLAGS else name in getattr(opts, "given", ())


def size_for_machine(sized_for: sizing.SizedFor | None, opts: Any = FLAGS) -> None:
    """Resolves ``auto`` in --num_workers / --envs_per_worker (integers in ``opts`` afterwards) and prints the
    choice. --envs_per_worker left at its default is auto when --num_workers is."""
    auto_workers = opts.num_workers == sizing.AUTO
    auto_envs = opts.envs_per_worker == sizing.AUTO or (auto_workers and not _given(opts, "envs_per_worker"))
    if not (auto_workers or auto_envs):
        return
    cores, recipe = sizing.available_cores(), sized_for or DEV_VM
    if auto_workers:
        opts.num_workers = sizing.auto_num_workers(cores, sizing.learner_on_cpu(opts.platform))
    if opts.num_workers < 1:
        raise FlagError(f"--num_workers must be at least 1, got {opts.num_workers}")
    if auto_envs:
        opts.envs_per_worker = sizing.auto_envs_per_worker(recipe.total_envs, opts.num_workers)
    workers = f"{opts.num_workers} worker{'s' if opts.num_workers != 1 else ''}"
    print(f"sized for this machine: {workers} x {opts.envs_per_worker} envs ({cores} cores; the recipe was sized "
          f"for {recipe})", flush=True)


def _resolve_pin_cpus(opts: Any) -> None:
    """Checks --pin_cpus and resolves ``auto`` (``sizing.auto_pin_cpus``; -1 where the OS sets no CPU affinity, or
    for --serial runs, whose workers are threads of this process) into ``opts``, printing the choice."""
    usable, affinity = sizing.available_cores(), hasattr(os, "sched_setaffinity")
    if opts.pin_cpus == sizing.AUTO:
        opts.pin_cpus = -1
        if affinity and not opts.serial:
            opts.pin_cpus = sizing.auto_pin_cpus(usable, opts.num_workers, sizing.learner_on_cpu(opts.platform))
        if opts.pin_cpus > 0:
            print(f"workers kept off {opts.pin_cpus} of the {usable} cores for the learner process (--pin_cpus="
                  f"{opts.pin_cpus}; -1 turns it off)", flush=True)
    elif not -1 <= opts.pin_cpus < usable:
        raise FlagError(f"--pin_cpus must be -1 (off), auto, or leave the workers at least one of the {usable} usable "
                        f"cores, got {opts.pin_cpus}")
    elif opts.pin_cpus >= 0 and not affinity:
        raise FlagError("--pin_cpus: this operating system sets no CPU affinity (Linux does); use -1 or auto")


def build_run(algo: str, task: str, recipe: Mapping[str, Any], task_recipe: Mapping[str, Any],
              default_total_steps: int,
              sized_for: sizing.SizedFor | None = None, opts: Any = FLAGS) -> tuple[Any, Any, Any, dict[str, Any]]:
    """Validates every flag; returns (RunConfig, algorithm module, algorithm config, task overrides).
    ``sized_for``: what the recipe was tuned on (``auto`` sizing splits its environments; default DEV_VM).
    ``opts``: the parsed flags, or an object with the same attributes (``unilab_jax.apps.api.train``'s options;
    ``config`` / ``task_config`` there may be dicts)."""
    import tasks
    from unilab_jax import algos
    from unilab_jax.algos import contract
    from unilab_jax.config import apply_overrides, parse_overrides
    from unilab_jax.training.trainer import RunConfig

    if opts.platform not in PLATFORMS:
        raise FlagError(f"--platform={opts.platform!r}: choose one of {PLATFORMS}")
    try:
        if opts.platform == "jax":
            import jax  # noqa: F401
        else:
            import unilab_mlx  # noqa: F401
    except ImportError as e:
        raise FlagError(f"--platform={opts.platform}: its packages are not installed ({e}); "
                        f"pip install 'unilab-jax[{opts.platform}]'") from e
    try:
        module = algos.get(algo)
    except ValueError as e:
        raise FlagError(str(e)) from e
    if opts.video_every > 0:
        _check_video()  # first: the headless GL choice must precede every import of mujoco (the task check's too)
    task_name = opts.task or task
    try:
        tasks.default_config(task_name)  # unknown names; a gym:ENV_ID that cannot be made or driven
    except ValueError as e:
        raise FlagError(f"--task={task_name!r}: {e}") from e
    size_for_machine(sized_for, opts)
    for name in ("num_workers", "envs_per_worker", "eval_envs"):
        if getattr(opts, name) < 1:
            raise FlagError(f"--{name} must be at least 1, got {getattr(opts, name)}")
    total = opts.total_steps if opts.total_steps is not None else default_total_steps
    if total < 1:
        raise FlagError(f"--total_steps must be positive, got {total}")
    for name in ("eval_every", "checkpoint_every", "video_every"):
        if getattr(opts, name) < 0:
            raise FlagError(f"--{name} must be >= 0, got {getattr(opts, name)}")
    config = apply_overrides(apply_overrides(module.Config(), dict(recipe)), parse_overrides(opts.config))
    task_overrides = {**dict(task_recipe if task_name == task else {}), **parse_overrides(opts.task_config)}
    task_config = apply_overrides(tasks.default_config(task_name), task_overrides)  # rejects unknown keys
    task_overrides = {k: getattr(task_config, k) for k in task_overrides}
    length = getattr(task_config, "episode_length", None)  # every task's; evaluations play whole episodes
    if isinstance(length, int) and length < 1:
        raise FlagError(f"--task_config episode_length must be positive, got {length}")
    try:  # the algorithm's own flag checks (platforms, task kind)
        contract.hooks(module).check_run(opts.platform, task_config, config)
    except ValueError as e:
        raise FlagError(str(e)) from e
    if opts.replay_dir and module.BUFFER != "replay":
        raise FlagError(f"--replay_dir: {algo} does not use a replay buffer")
    if opts.replay_on_device == "on" and (module.BUFFER != "replay" or opts.platform != "jax" or opts.replay_dir):
        raise FlagError("--replay_on_device=on needs an off-policy algorithm, --platform=jax and no --replay_dir")
    for name, choices in (("replay_on_device", ("auto", "on", "off")), ("utd_mode", ("hold", "free")),
                          ("precompile", ("auto", "on", "off"))):
        if getattr(opts, name) not in choices:  # absl checks the flags; train()'s keywords are checked here
            raise FlagError(f"--{name}={getattr(opts, name)!r}: choose one of {choices}")
    try:
        compile_cache.check(opts.compilation_cache, "--compilation_cache")
    except ValueError as e:
        raise FlagError(str(e)) from None
    if not 0.0 <= opts.replay_hot_fraction <= 1.0:
        raise FlagError(f"--replay_hot_fraction must be in [0, 1], got {opts.replay_hot_fraction}")
    _resolve_pin_cpus(opts)
    if opts.utd_window < 0:
        raise FlagError(f"--utd_window must be >= 0, got {opts.utd_window}")
    if opts.utd_window and (module.BUFFER != "replay" or opts.utd_mode != "hold"):
        raise FlagError("--utd_window needs an off-policy algorithm and --utd_mode=hold")
    if opts.replay_disk_gb <= 0 or opts.replay_chunk_rows < 0:
        raise FlagError("--replay_disk_gb must be positive and --replay_chunk_rows >= 0")
    if module.BUFFER == "replay" and not opts.ray_address:  # the trainer's split of replay_capacity (Ray: per host)
        from unilab_jax.runtime.buffers import ReplayBuffer

        rows = opts.num_workers * ReplayBuffer.worker_rows(max(config.replay_capacity // opts.num_workers, 1),
                                                            opts.envs_per_worker)
        if max(config.learning_starts, config.batch_size) > rows:
            raise FlagError(f"learning_starts/batch_size ({max(config.learning_starts, config.batch_size)}) exceed "
                            f"the replay capacity ({rows} transitions over {opts.num_workers} workers): raise "
                            "replay_capacity")
    batch = config.horizon * opts.num_workers * opts.envs_per_worker
    if module.BUFFER == "trajectory" and batch < config.num_minibatches:
        raise FlagError(f"a batch of {batch} transitions cannot make {config.num_minibatches} minibatches")
    if opts.devices != "1":
        if opts.platform != "jax":
            raise FlagError(f"--devices={opts.devices}: data-parallel learners are JAX's (--platform=jax)")
        from unilab_jax.training import sharding

        try:
            sharding.check_run(opts.devices, opts.platform, config, module.BUFFER, opts.num_workers,
                               opts.envs_per_worker, opts.device_split)
        except ValueError as e:
            raise FlagError(str(e)) from e
    if opts.wandb_project:
        import importlib.util

        if importlib.util.find_spec("wandb") is None:
            raise FlagError("--wandb_project: wandb is not installed; pip install 'unilab-jax[wandb]'")
    if opts.ray_address or opts.ray_workers_per_host:
        _check_ray_flags(module, opts)
    logdir = opts.logdir or os.path.join("runs", f"{algo}_{task_name}_s{opts.seed}")
    if opts.resume and not os.path.isdir(os.path.join(logdir, "checkpoints")):
        raise FlagError(f"--resume: no checkpoints under {logdir!r}")
    if opts.resume and hasattr(task_config, "init_level_weights") and "init_level_weights" not in task_overrides:
        # the workers' terrain curricula are not in the checkpoint: the resumed robots start at the levels the
        # run's robots stood at when it stopped (its metrics' last level histogram), not at the initial levels
        from tasks import rough

        weights = rough.resumed_level_weights(os.path.join(logdir, "metrics.jsonl"), task_config.terrain_levels,
                                              task_config.episode_length * task_config.ctrl_dt)
        if weights:
            task_overrides["init_level_weights"] = weights
            print(f"--resume: terrain levels drawn from the run's last level distribution {weights}", flush=True)
    try:
        os.makedirs(logdir, exist_ok=True)
    except OSError as e:
        raise FlagError(f"--logdir={logdir!r} cannot be created: {e}") from e
    run = RunConfig(algo=algo, task=task_name, platform=opts.platform, num_workers=opts.num_workers,
                    envs_per_worker=opts.envs_per_worker, total_steps=total, seed=opts.seed, logdir=logdir,
                    resume=opts.resume, eval_every=opts.eval_every, eval_envs=opts.eval_envs,
                    eval_process=opts.eval_process,
                    checkpoint_every=opts.checkpoint_every, serial=opts.serial, replay_dir=opts.replay_dir,
                    replay_disk_gb=opts.replay_disk_gb, replay_hot_fraction=opts.replay_hot_fraction,
                    replay_chunk_rows=opts.replay_chunk_rows, keep_replay=opts.keep_replay,
                    replay_on_device=opts.replay_on_device,
                    precompile=opts.precompile,
                    utd_mode=opts.utd_mode, utd_window=opts.utd_window, pin_cpus=opts.pin_cpus,
                    video_every=opts.video_every, devices=opts.devices, device_split=opts.device_split,
                    ray_address=opts.ray_address,
                    ray_workers_per_host=opts.ray_workers_per_host, wandb_project=opts.wandb_project,
                    profile_dir=opts.profile_dir, profile_start=opts.profile_start,
                    profile_updates=opts.profile_updates, compilation_cache=opts.compilation_cache)
    return run, module, config, task_overrides


def _check_ray_flags(module: Any, opts: Any = FLAGS) -> None:
    """``--ray_address`` / ``--ray_workers_per_host`` checks (no connection is made here)."""
    import importlib.util

    from unilab_jax.runtime.ray_pool import check_address

    if not opts.ray_address:
        raise FlagError("--ray_workers_per_host needs --ray_address")
    try:
        check_address(opts.ray_address)
    except ValueError as e:
        raise FlagError(str(e)) from e
    if module.BUFFER != "replay":
        raise FlagError("--ray_address: Ray rollouts carry replay transitions (off-policy algorithms only)")
    if opts.serial:
        raise FlagError("--ray_address runs worker processes on every host: it cannot be combined with --serial")
    if opts.ray_workers_per_host < 0:
        raise FlagError(f"--ray_workers_per_host must be >= 0, got {opts.ray_workers_per_host}")
    if importlib.util.find_spec("ray") is None:
        raise FlagError("--ray_address: Ray is not installed; pip install 'unilab-jax[ray]'")


def _check_video() -> None:
    """``--video_every``: headless GL chosen before mujoco is imported, and a frame rendered here, before anything
    starts (in a fresh interpreter: a failed GL setup can leave a process unusable)."""
    from unilab_jax.robots import gl

    gl.prefer_headless()
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError as e:
        raise FlagError(f"--video_every needs imageio and imageio-ffmpeg: pip install 'unilab-jax[video]' ({e})") from e
    reason = gl.probe(os.environ.get("MUJOCO_GL", ""))
    if reason is not None:
        raise FlagError(f"--video_every: MuJoCo cannot render here ({reason}); on headless Linux install libegl1 "
                        "libegl-mesa0 libgl1-mesa-dri libopengl0 (MUJOCO_GL=egl) or libosmesa6 (MUJOCO_GL=osmesa)")


TENSORBOARD_HINT = "pip install 'unilab-jax[tensorboard]' for the viewer"


def report(summary: Mapping[str, Any]) -> None:
    """Prints a finished run's summary, where its logs are and how to view them, and its warning (a run that
    made no learner update, or fewer than asked) last, where it is seen."""
    print(json.dumps(summary, indent=2))
    print(f"logs: {summary['logdir']}  (view: tensorboard --logdir {summary['logdir']}; {TENSORBOARD_HINT})")
    if "checkpoints" in summary:  # the MJX loop keeps none
        print(f"checkpoints: {summary['checkpoints']}")
    if summary.get("warning"):
        print(f"warning: {summary['warning']}", flush=True)


def launch(validate: Callable[[], Any], train: Callable[[Any], None],
           errors: tuple[type[Exception], ...] = (), help: Callable[[], str] | None = None) -> None:
    """The absl ``main`` of every experiment launcher: quiet logging unless ``-v`` is given (orbax logs every
    save at INFO; this package's own INFO lines, the start-up milestones and what a resume restored, stay),
    no stray arguments, ``validate()`` -- a flag or config error (or one of ``errors``) exits
    with code 2 and a message before anything starts -- then ``train(validate())``, where a damaged checkpoint
    or replay index (found when it is opened, before training) exits with code 2 and its message too."""

    def main(argv: list[str]) -> None:
        if not any(a.startswith(("-v", "--v")) for a in sys.argv[1:]):
            absl_logging.set_verbosity(absl_logging.WARNING)
            logging.getLogger("unilab_jax").setLevel(logging.INFO)
        if len(argv) > 1:
            raise app.UsageError(f"unexpected arguments: {argv[1:]}")
        from unilab_jax.config import ConfigError

        try:
            validated = validate()
        except (FlagError, ConfigError, *errors) as e:
            print(f"error: {e}", file=sys.stderr)
            sys.exit(2)
        from unilab_jax.checkpoint import CheckpointCorruptError
        from unilab_jax.runtime.replay_store import StoreCorruptError

        try:
            train(validated)
        except (CheckpointCorruptError, StoreCorruptError) as e:  # damaged saved data, found before training
            print(f"error: {e}", file=sys.stderr)
            sys.exit(2)
        from unilab_jax.training.threads import learner_busy, stopped_by_signal

        if learner_busy() or stopped_by_signal():  # a stopped run: saved and closed, leave without teardown
            logging.shutdown()
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)

    if help is not None:  # before absl: its --help lists no flag of ours and exits 1
        from unilab_jax.apps import cli_help

        cli_help.exit_on_help(help)
    app.run(main)


def new_trainer(cls: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """``cls(*args, **kwargs)``, a trainer: it builds a probe of the task and the learner, before any worker starts,
    so a ValueError there (a task config the task refuses) exits with code 2 and its message."""
    try:
        return cls(*args, **kwargs)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)


def run_experiment(algo: str, task: str, recipe: Mapping[str, Any] | None = None,
                   task_recipe: Mapping[str, Any] | None = None, default_total_steps: int = 1_000_000,
                   sized_for: sizing.SizedFor | None = None) -> None:
    """Parses the shared flags, validates them, trains, prints the summary. A recipe that gives ``sized_for``
    (what it was tuned on) defaults to ``--num_workers=auto``; one that does not, to DEV_VM's 2 x 32."""

    def train(parts: tuple) -> None:
        from unilab_jax.training.trainer import Trainer

        report(new_trainer(Trainer, *parts, start_time=PROCESS_START).train())

    if sized_for is not None:
        FLAGS.set_default("num_workers", sizing.AUTO)
    launch(lambda: build_run(algo, task, recipe or {}, task_recipe or {}, default_total_steps, sized_for), train,
           help=lambda: help_text(algo, task, recipe or {}, task_recipe or {}, default_total_steps))
