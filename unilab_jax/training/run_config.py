"""``RunConfig``: everything about a run that is not an algorithm or task hyperparameter (the trainer's options;
``apps/cli.py`` sets each field from the flag of its name, ``unilab_jax.train`` from the keyword)."""

from __future__ import annotations

import dataclasses

import tasks
from unilab_jax import algos
from unilab_jax.training import compile_cache


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Everything about a run that is not an algorithm or task hyperparameter."""

    algo: str
    task: str
    platform: str = "jax"
    num_workers: int = 2
    envs_per_worker: int = 32
    total_steps: int = 100_000
    seed: int = 0
    logdir: str = "runs/default"
    resume: bool = False
    eval_every: int = 0  # env steps between evaluations (0: only at the end)
    eval_envs: int = 16
    checkpoint_every: int = 0  # env steps between checkpoints (0: at evaluations and at the end)
    video_every: int = 0  # env steps between clips of an evaluation episode (evaluation.py ClipRecorder; 0: none)
    serial: bool = False  # run the workers in-process (debugging, deterministic tests)
    # Persistent replay (off-policy algorithms; unilab_jax/runtime/replay_store.py): every transition is
    # also written to a crash-safe store in replay_dir, which --resume reopens.
    replay_dir: str = ""  # "" keeps replay in shared memory only
    replay_disk_gb: float = 10.0  # disk budget of the store; the oldest chunks are deleted past it
    replay_hot_fraction: float = 0.5  # share of each minibatch drawn from the shared-memory rings
    replay_chunk_rows: int = 0  # transitions per committed chunk (0: ~16 MiB); a SIGKILL loses at most one
    keep_replay: bool = False  # off-policy: the rings kept across an orderly stop (training/ring_snapshot.py)
    # Off-policy, JAX learner: mirror the rings in accelerator memory and sample there (training/device_replay.py).
    # "auto": on when JAX's default backend is not the CPU and there is no replay_dir; "on" / "off" force it.
    replay_on_device: str = "auto"
    # Evaluations' episodes in a process of their own (training/evaluation.py EvaluationProcess), off the learner
    # process's interpreter lock. "auto": when the learner runs on an accelerator (JAX not on the CPU, MLX on the
    # GPU) and the run is not serial; "on" / "off" force it.
    eval_process: str = "auto"
    # Off-policy, JAX learner: compile the update from the start, while the workers start and the
    # rings fill (Trainer._start_precompile). "auto": when the learner runs on an accelerator (on the CPU the compile
    # would take the workers' cores); "on" / "off" force it.
    precompile: str = "auto"
    # Off-policy: "hold" pauses the workers when the learner falls more than ``utd_window`` env steps behind
    # the recipe's update-to-data ratio (the same learning per env step on any machine); "free" lets them
    # run on (a learner slower than ``utd`` x the env rate then trains below the ratio). See ReplaySource.
    utd_mode: str = "hold"
    utd_window: int = 0  # env steps the workers may run ahead of the ratio (0: four learner calls' worth)
    # Worker CPU affinity: -1 none; K >= 0: workers pinned to the usable CPUs except the first K, which stay free
    # for the learner process (runtime/spawn.py cpu_placement).
    pin_cpus: int = -1
    # JAX learner: "1" (one device, the plain path), "N" or "all": data-parallel over the first N local devices
    # (unilab_jax/training/sharding.py; the batch axis must divide evenly).
    devices: str = "1"
    # With devices > 1: what is split over them, "batch" (data parallel) or "critics" (an off-policy learner's critic
    # ensemble, its members divided over the devices; training/sharding.py).
    device_split: str = "batch"
    # Off-policy: rollouts on every node of a Ray cluster ("auto" or HOST:PORT of its head; "" = this host only,
    # Ray not imported). The learner's node runs num_workers workers, every other node ray_workers_per_host
    # (0: num_workers). unilab_jax/runtime/ray_pool.py.
    ray_address: str = ""
    ray_workers_per_host: int = 0
    wandb_project: str = ""  # also log to this Weights & Biases project (metrics.MetricLogger; "" = no W&B)
    # JAX learner: a jax.profiler trace of updates [profile_start, profile_start + profile_updates) into profile_dir
    # ("" = none; training/profiling.py)
    profile_dir: str = ""
    profile_start: int = 300
    profile_updates: int = 30
    # JAX learner: JAX's persistent compilation cache, so a run's programs compiled by an earlier run load instead of
    # compiling (training/compile_cache.py). "auto": under ~/.cache/unilab_jax/xla when the learner runs on an
    # accelerator (its update takes 10-13 s to compile on the H100 machine); "off"; or a directory. A
    # JAX_COMPILATION_CACHE_DIR in the environment wins over both.
    compilation_cache: str = "auto"

    def __post_init__(self) -> None:
        """The checks that need nothing started: names that exist, counts that can run (``apps.cli.build_run``
        checks the rest, against the algorithm's and task's configs)."""
        if self.algo not in algos.names():
            raise ValueError(f"RunConfig: unknown algorithm {self.algo!r}; registered: {algos.names()}")
        if not self.task.startswith("gym:") and self.task not in tasks.names():
            raise ValueError(f"RunConfig: unknown task {self.task!r}; registered: {tasks.names()} (or gym:ENV_ID)")
        for name in ("num_workers", "envs_per_worker", "total_steps", "eval_envs", "profile_updates"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise ValueError(f"RunConfig: {name} must be a positive integer, got {getattr(self, name)!r}")
        for name in ("eval_every", "checkpoint_every", "video_every", "utd_window", "ray_workers_per_host",
                     "profile_start"):
            if getattr(self, name) < 0:
                raise ValueError(f"RunConfig: {name} must be >= 0, got {getattr(self, name)!r}")
        for name, choices in (("platform", ("jax", "mlx")), ("utd_mode", ("hold", "free")),
                              ("replay_on_device", ("auto", "on", "off")), ("eval_process", ("auto", "on", "off")),
                              ("precompile", ("auto", "on", "off")), ("device_split", ("batch", "critics"))):
            if getattr(self, name) not in choices:
                raise ValueError(f"RunConfig: {name} must be one of {choices}, got {getattr(self, name)!r}")
        compile_cache.check(self.compilation_cache, "RunConfig: compilation_cache")
