"""The training loop for trajectory (on-policy) algorithms: PPO and APPO.

Workers collect into shared-memory slots while the learner updates; a prefetch thread pulls the
next batch and moves it to the device while the jitted update of the previous one runs. In
lock-step mode the workers wait for the new weights; in async mode they never wait and the
policy lag (learner version minus the version that produced each transition) is logged.

Stopping: SIGINT and SIGTERM set a stop flag that every wait of the main thread checks. The learner's
own calls (the update, whose first call compiles, and the weight download) run in a dedicated thread
(:class:`LearnerThread`), so a stop never waits long for them: an update in flight gets
``_STOP_GRACE_S`` to finish (a steady GPU update takes milliseconds), then it is abandoned, the state
saved is the one of the last completed update, and the process leaves the abandoned call behind
(``learner_busy()``). After a stopped run the CLI exits without the interpreter's teardown: it would wait
for an abandoned call, and once (a fresh-clone CI) it aborted (exit -6) in third-party teardown after a
complete summary; everything the run owns is saved and closed by then. Updates donate their input only on
accelerators, where the one call that can outlast the grace is the first compile, before any
donation; on the CPU, where an update can take minutes, nothing is donated.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import queue
import signal
import threading
import time
import weakref
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any

import numpy as np

from unilab_jax import algos, nets
from unilab_jax.core import rlpd
from unilab_jax.fields import TRAJECTORY_FIELDS, prior_fields, replay_fields
from unilab_jax.metrics import WALKING, MetricLogger, ProgressBar
from unilab_jax.runtime.ring import StopRequested
from unilab_jax.xp import end_thread, tree_leaves

log = logging.getLogger(__name__)


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
    video_every: int = 0  # env steps between clips of an evaluation episode (unilab_jax.play.ClipRecorder; 0: none)
    serial: bool = False  # run the workers in-process (debugging, deterministic tests)
    # Persistent replay (off-policy algorithms; unilab_jax/runtime/replay_store.py): every transition is
    # also written to a crash-safe store in replay_dir, which --resume reopens.
    replay_dir: str = ""  # "" keeps replay in shared memory only
    replay_disk_gb: float = 10.0  # disk budget of the store; the oldest chunks are deleted past it
    replay_hot_fraction: float = 0.5  # share of each minibatch drawn from the shared-memory rings
    replay_chunk_rows: int = 0  # transitions per committed chunk (0: ~16 MiB); a SIGKILL loses at most one
    # Off-policy, JAX learner: mirror the rings in accelerator memory and sample there (unilab_jax/device_replay.py).
    # "auto": on when JAX's default backend is not the CPU and there is no replay_dir; "on" / "off" force it.
    replay_on_device: str = "auto"
    # Off-policy: "hold" pauses the workers when the learner falls more than ``utd_window`` env steps behind
    # the recipe's update-to-data ratio (the same learning per env step on any machine); "free" lets them
    # run on (a learner slower than ``utd`` x the env rate then trains below the ratio). See _ReplaySource.
    utd_mode: str = "hold"
    utd_window: int = 0  # env steps the workers may run ahead of the ratio (0: four learner calls' worth)
    # Worker CPU affinity: -1 none; K >= 0: workers pinned to the usable CPUs except the first K, which stay free
    # for the learner process (runtime/pool.py cpu_placement).
    pin_cpus: int = -1
    # JAX learner: "1" (one device, the plain path), "N" or "all": data-parallel over the first N local devices
    # (unilab_jax/sharding.py; the batch axis must divide evenly).
    devices: str = "1"
    # Off-policy: rollouts on every node of a Ray cluster ("auto" or HOST:PORT of its head; "" = this host only,
    # Ray not imported). The learner's node runs num_workers workers, every other node ray_workers_per_host
    # (0: num_workers). unilab_jax/runtime/ray_pool.py.
    ray_address: str = ""
    ray_workers_per_host: int = 0


def _learner_platform(platform: str) -> Any:
    """Backend used to convert numpy batches for the learner."""
    from unilab_jax import xp as shim

    return shim.get(platform)


def _donated(tree: Any) -> bool:
    """Whether any leaf is a JAX array whose buffer was donated to a computation."""
    return any(getattr(leaf, "is_deleted", lambda: False)() for leaf in tree_leaves(tree))


class Trainer:
    _STOP_GRACE_S = 2.0  # after a stop, how long the loop still waits for the update in flight
    def __init__(self, run: RunConfig, algo_module: Any, algo_config: Any, task_overrides: dict[str, Any],
                 start_time: float | None = None, eval_overrides: dict[str, Any] | None = None):
        """``start_time``: wall clock that ``time/wall_s`` and ``eval/wall_s`` count from (the process
        start when launched from the CLI, so compilation and worker start-up are included).
        ``eval_overrides``: task overrides added for evaluations only (e.g. robot tasks evaluating on
        the robots that answer, ``min_envs``)."""
        import tasks

        self.t0 = time.time() if start_time is None else start_time

        self.run, self.algo, self.config, self.task_overrides = run, algo_module, algo_config, task_overrides
        self.eval_overrides = {**task_overrides, **(eval_overrides or {})}
        probe = tasks.make(run.task, num_envs=1, seed=run.seed, overrides=task_overrides)
        self.spec = probe.spec
        probe.close()
        self.xp = _learner_platform(run.platform)
        self.learner = algos.make_learner(algo_module, run.platform, algo_config, self.spec)
        self.parallel = None  # the DataParallel learner of --devices > 1
        if run.devices != "1":
            from unilab_jax import sharding

            self.parallel = sharding.for_run(self.learner, run, algo_config, algo_module.BUFFER)
            self.learner = self.parallel or self.learner
        self.batch_xp = self.parallel or self.xp  # what the batch sources place host arrays with (from_numpy)
        self.logger = MetricLogger(run.logdir)
        self.ckpt_dir = os.path.join(os.path.abspath(run.logdir), "checkpoints")
        self._stop = threading.Event()
        self._resumed_meta: dict[str, Any] = {}  # meta of the checkpoint this run resumed from

    # -- state -----------------------------------------------------------------------------------
    def _init_state(self) -> tuple[Any, dict[str, int]]:
        state = self.learner.init(self.xp.random.key(self.run.seed))
        counters = {"env_steps": 0, "updates": 0, "version": 0, "episodes": 0}
        if self.run.resume:
            from unilab_jax.checkpoint import Checkpointer

            ckpt = Checkpointer(self.ckpt_dir)
            if ckpt.latest_step() is None:
                raise FileNotFoundError(f"--resume: no checkpoint under {self.ckpt_dir}")
            state, meta = ckpt.restore(state, lambda a, like: self.xp.from_numpy(a))
            ckpt.close()
            if self.parallel is not None:
                state = self.parallel.replicate(state)
            self._resumed_meta = meta
            counters = {k: int(v) for k, v in meta["counters"].items()}
            if meta.get("task") != self.run.task or meta.get("algo") != self.run.algo:
                raise ValueError(f"--resume: checkpoint is {meta.get('algo')}/{meta.get('task')}, "
                                 f"not {self.run.algo}/{self.run.task}")
        return state, counters

    def _meta(self, counters: dict[str, int], source: Any = None) -> dict[str, Any]:
        meta = {"counters": dict(counters), "algo": self.run.algo, "task": self.run.task,
                "run": dataclasses.asdict(self.run), "config": dataclasses.asdict(self.config),
                "task_overrides": {k: str(v) for k, v in self.task_overrides.items()}}
        replay = source.checkpoint_meta() if source is not None else None
        if replay is not None:
            meta["replay"] = replay
        return meta

    def _device_replay(self, pool: Any) -> Any:
        """The accelerator-side replay mirror, or None (see ``RunConfig.replay_on_device``)."""
        mode = self.run.replay_on_device
        if mode not in ("auto", "on", "off"):
            raise ValueError(f"replay_on_device must be auto, on or off, got {mode!r}")
        if mode == "off" or self.run.platform != "jax" or self.run.replay_dir:
            if mode == "on":
                raise ValueError("replay_on_device=on needs the jax platform and no replay_dir")
            return None
        import jax

        if mode == "auto" and jax.default_backend() == "cpu":
            return None
        from unilab_jax.device_replay import DeviceReplay

        return DeviceReplay(pool.buffer, replay_fields(self.spec), self.parallel)

    def _row_layout(self, names: tuple[str, ...]) -> dict[str, Any]:
        """The (shape, dtype) of the transition fields ``names`` for this run's task and algorithm."""
        from unilab_jax.runtime.buffers import transition_layout

        fields = transition_layout(self.spec, self.algo.extras(self.spec.action_dim))
        return {k: fields[k] for k in names}

    def _open_replay_store(self) -> Any:
        """The persistent replay store of ``run.replay_dir`` (None when off).

        A fresh run refuses a store that already holds transitions (of an earlier run: pass
        ``--resume``), and any run refuses a store of another task.
        """
        run = self.run
        if not run.replay_dir:
            return None
        from unilab_jax.runtime.replay_store import ReplayStore

        store = ReplayStore(run.replay_dir, self._row_layout(replay_fields(self.spec)),
                            chunk_rows=run.replay_chunk_rows, max_bytes=int(run.replay_disk_gb * 1e9),
                            info={"task": run.task, "algo": run.algo})
        problem = None
        if store.info.get("task") != run.task:
            problem = f"it holds transitions of task {store.info.get('task')!r}"
        elif store.committed and not run.resume:
            problem = (f"it already holds {store.committed} transitions of an earlier run; pass --resume to "
                       "continue that run, or choose an empty directory")
        if problem:
            store.close()
            raise ValueError(f"replay_dir={run.replay_dir!r}: {problem}")
        recorded = (self._resumed_meta.get("replay") or {}).get("store_committed")
        if recorded is not None and store.committed != recorded:
            log.warning("replay store %s: %d transitions committed, the checkpoint recorded %d (%s)", run.replay_dir,
                        store.committed, recorded, "kept: written after the checkpoint" if store.committed > recorded
                        else "chunks were lost or the directory changed")
        return store

    def _load_prior(self) -> dict[str, np.ndarray] | None:
        """The prior data of ``config.prior_dir`` (RLPD's symmetric sampling; None when the algorithm has none)."""
        directory = getattr(self.config, "prior_dir", "")
        if not directory:
            return None
        from unilab_jax.runtime.prior import load_prior

        prior = load_prior(directory, self._row_layout(prior_fields(self.spec)))
        log.info("prior data: %d transitions from %s", len(prior["reward"]), directory)
        return prior

    # -- evaluation ------------------------------------------------------------------------------
    def evaluate(self, weights: dict, seed: int, stop: threading.Event | None = None) -> dict[str, float]:
        """Deterministic policy, one full episode in each of ``eval_envs`` environments (or as many as the
        task could build, e.g. the robots that answer); raises :class:`StopRequested` when ``stop`` is set
        before it ends."""
        import tasks
        from unilab_jax.play import deterministic_policy, run_episodes

        task = tasks.make(self.run.task, num_envs=self.run.eval_envs, seed=10_000 + seed,
                          overrides=self.eval_overrides)
        if hasattr(task, "set_operator"):  # the policy alone: no operator interventions while evaluating
            task.set_operator("off")
        try:  # on locomotion tasks with the walking metric: velocity tracking, independent of reward scaling
            _, stats = run_episodes(task, deterministic_policy(self.algo, weights, task), stop=stop)
        finally:
            task.close()
        result = {f"eval/{k}": v for k, v in stats.items()}
        if "tracking_error" in stats:  # locomotion: the walking criterion on the same episodes
            result["eval/walking"] = float(WALKING.met(stats))  # 1: it walks
        return result

    # -- the loop ----------------------------------------------------------------------------------
    def train(self) -> dict[str, Any]:
        from unilab_jax.checkpoint import Checkpointer
        from unilab_jax.runtime.pool import WorkerPool, cpu_placement
        from unilab_jax.runtime.weights import WeightPublisher
        from unilab_jax.runtime.worker import PREFETCH_MIN_BYTES

        run, cfg, t_start, stop = self.run, self.config, self.t0, self._stop
        evaluator = _AsyncEvaluator(self, stop)
        learner = LearnerThread(run.platform)
        state, counters = self._init_state()
        weights = nets.to_numpy(self.learner.weights(state))
        clips = None
        if run.video_every:
            from unilab_jax.play import ClipRecorder

            clips = ClipRecorder(self, run.video_every, counters["env_steps"])
        replay = self.algo.BUFFER == "replay"
        hold_window = self._hold_window(cfg) if replay else None
        # Opened before any worker starts or checkpoint is written, so a refused store changes nothing.
        store = self._open_replay_store() if replay else None
        prior = self._load_prior() if replay else None
        pool_kwargs = dict(task_name=run.task, task_overrides=self.task_overrides, num_workers=run.num_workers,
                           envs_per_worker=run.envs_per_worker, seed=run.seed + counters["updates"],
                           algo_module=self.algo.__name__, weight_template=weights,
                           horizon=getattr(cfg, "horizon", 32), serial=run.serial,
                           replay_capacity=max(getattr(cfg, "replay_capacity", 0) // run.num_workers, 1)
                           if replay else 0,
                           max_env_steps=max(run.total_steps - counters["env_steps"], 0) if replay else None)
        if run.ray_address:
            from unilab_jax.runtime.ray_pool import RayPool

            pool = RayPool(run.ray_address, workers_per_host=run.ray_workers_per_host or None, **pool_kwargs)
        else:
            pool = WorkerPool(**pool_kwargs, worker_cpus=cpu_placement(run.num_workers, run.pin_cpus)
                              if run.pin_cpus >= 0 and not run.serial else None)
        # Large weights of an asynchronous run are written by a background thread (the learner updates on);
        # lock-step, serial and Ray runs publish inline.
        publisher = (WeightPublisher(pool.publish) if replay and isinstance(pool, WorkerPool) and not run.serial
                     and pool.weights.nbytes >= PREFETCH_MIN_BYTES else None)
        ckpt = Checkpointer(self.ckpt_dir)
        restore_signals = stop_on_signals(stop)
        next_eval = counters["env_steps"] + run.eval_every if run.eval_every else None
        next_ckpt = counters["env_steps"] + run.checkpoint_every if run.checkpoint_every else None
        last_eval: dict[str, float] = {}
        evaluated_at = -1  # env steps of the last periodic evaluation
        interrupted = False
        diverged: LearningDiverged | None = None
        prefetch: _Prefetcher | None = None
        source: _ReplaySource | _TrajectorySource | None = None
        progress = ProgressBar(run.total_steps, counters["env_steps"])
        try:
            pool.start(stop=stop.is_set)
            # The source before the first weights: replay workers wait for them, so a held run's step
            # limit is in place before any env step.
            source = (_ReplaySource(pool, self.batch_xp, cfg, counters, run.seed, store, run.replay_hot_fraction,
                                    self._resumed_meta.get("replay"), self._device_replay(pool),
                                    total_steps=run.total_steps, hold_window=hold_window, prior=prior)
                      if replay else _TrajectorySource(pool, self.batch_xp, self.spec.reward_terms))
            pool.publish(weights, counters["version"])
            prefetch = _Prefetcher(source.produce, inline=run.serial)
            t_last, steps_last = time.time(), counters["env_steps"]
            while counters["env_steps"] < run.total_steps and not stop.is_set():
                t_wait = time.perf_counter()
                batch, stats = prefetch.get(stop)
                t_update = time.perf_counter()
                state, scalars = learner.call(stop, self._update, state, batch, grace_s=self._STOP_GRACE_S)
                t_publish = time.perf_counter()
                counters["updates"] += 1
                publish = source.advance(counters, stats)
                bad = sorted(k for k, v in scalars.items() if not math.isfinite(v))
                if bad:  # before the weights reach the workers or a checkpoint
                    raise LearningDiverged(bad, counters, ckpt.latest_step())
                if publish:
                    counters["version"] += 1
                    host = learner.call(stop, self._numpy_weights, state)
                    (publisher.submit if publisher is not None else pool.publish)(host, counters["version"])
                now = time.time()
                scalars.update({"perf/learner_wait_s": t_update - t_wait, "perf/update_s": t_publish - t_update,
                                "perf/publish_s": time.perf_counter() - t_publish})
                scalars.update(stats["scalars"])
                scalars.update(source.pool_scalars())
                if self.spec.success_on_termination and "episode/terminated_fraction" in scalars:
                    scalars["episode/success_rate"] = scalars["episode/terminated_fraction"]
                scalars.update({"perf/env_steps_per_s": (counters["env_steps"] - steps_last) / max(now - t_last, 1e-9),
                                "perf/learner_updates_per_s": 1.0 / max(now - t_last, 1e-9),
                                "time/wall_s": now - t_start})
                t_last, steps_last = now, counters["env_steps"]
                self.logger.log(counters["env_steps"], scalars)
                progress.update(counters["env_steps"], scalars.get("episode/return"))
                if next_eval is not None and counters["env_steps"] >= next_eval:
                    evaluator.submit(learner.call(stop, self._numpy_weights, state), dict(counters),
                                     time.time() - t_start)
                    evaluated_at = counters["env_steps"]
                    next_eval += run.eval_every
                    ckpt.save(counters["env_steps"], state, self._meta(counters, source))
                if clips is not None and clips.due(counters["env_steps"]):
                    clips.submit(learner.call(stop, self._numpy_weights, state), counters["env_steps"])
                if next_ckpt is not None and counters["env_steps"] >= next_ckpt:
                    ckpt.save(counters["env_steps"], state, self._meta(counters, source))
                    next_ckpt += run.checkpoint_every
        except (KeyboardInterrupt, StopRequested):
            interrupted = True
        except LearningDiverged as e:
            diverged = e
        finally:
            progress.close()
            if prefetch is not None:
                prefetch.stop()
            if source is not None:
                source.stop()  # the last spill to disk, while the rings still exist
            if publisher is not None:
                publisher.close()
            pool.close()
            if prefetch is not None:
                prefetch.join()
            if diverged is None:  # a diverged state is not saved: the last checkpoint stands
                self._final_save(ckpt, counters, state, source)
            ckpt.close()
            if store is not None:
                store.close()
            learner.close()
            restore_signals()
        interrupted = interrupted or stop.is_set() or diverged is not None
        if not interrupted and evaluated_at != counters["env_steps"]:
            evaluator.submit(self._numpy_weights(state), dict(counters), time.time() - t_start)
        last_eval = evaluator.close(cancel=interrupted)
        if clips is not None:
            clips.close(cancel=interrupted)
        self.logger.close()
        summary = {"env_steps": counters["env_steps"], "updates": counters["updates"],
                   "wall_s": time.time() - t_start, "logdir": os.path.abspath(run.logdir),
                   "checkpoints": self.ckpt_dir, "interrupted": interrupted, **last_eval}
        if diverged is not None:
            summary["diverged"] = str(diverged)
        with open(os.path.join(run.logdir, "summary.json"), "w") as f:
            json.dump(summary, f, indent=2)
        if diverged is not None:
            raise diverged
        return summary

    def _final_save(self, ckpt: Any, counters: dict[str, int], state: Any, source: Any) -> None:
        """The end-of-run checkpoint. On an accelerator the update donates its input, so when a stop left
        an update running (a first compile that outlasted ``_STOP_GRACE_S``) the state's buffers may now be
        the update's: then the last checkpoint written stands, and a warning says which."""
        try:
            if not _donated(state):
                ckpt.save(counters["env_steps"], state, self._meta(counters, source))
                return
        except Exception:
            if not _donated(state):
                raise
        log.warning("final checkpoint skipped: the update left running took the state's buffers; the last "
                    "checkpoint (env step %s) stands", ckpt.latest_step())

    def _update(self, state: Any, batch: dict) -> tuple[Any, dict[str, float]]:
        """One learner update and its losses as floats (which waits for the update to finish)."""
        state, metrics = self.learner.update(state, batch)
        return state, {f"loss/{k}": float(v) for k, v in metrics.items()}

    def _hold_window(self, cfg: Any) -> int | None:
        """Env steps the replay workers may run ahead of ``utd``; None in "free" mode. The default, four
        learner calls' worth (at least four steps of every env), absorbs the jitter of a learner that
        keeps pace on average."""
        if self.run.utd_mode not in ("hold", "free"):
            raise ValueError(f"utd_mode must be hold or free, got {self.run.utd_mode!r}")
        if self.run.utd_mode == "free":
            return None
        if self.run.utd_window < 0:
            raise ValueError(f"utd_window must be >= 0, got {self.run.utd_window}")
        return self.run.utd_window or max(4 * math.ceil(cfg.updates_per_call / cfg.utd),
                                          4 * self.run.num_workers * self.run.envs_per_worker)

    def _numpy_weights(self, state: Any) -> dict:
        return nets.to_numpy(self.learner.weights(state))


class LearningDiverged(FloatingPointError):
    """An update returned a non-finite loss. The trainer stops at once, saves no checkpoint of the
    diverged state (the last one written stands), flushes the metrics, writes ``summary.json`` with
    ``"diverged"`` set to this message, and raises this error."""

    def __init__(self, names: list[str], counters: dict[str, int], last_checkpoint: int | None):
        where = (f"the last checkpoint, env step {last_checkpoint}, stands" if last_checkpoint is not None
                 else "no checkpoint was written before it")
        super().__init__(f"learning diverged: non-finite {', '.join(names)} at update {counters['updates']} "
                         f"(env step {counters['env_steps']}); {where}. Lower the learning rates or the "
                         "update-to-data ratio, or clip gradients (max_grad_norm), and --resume.")
        self.names = names


def stop_on_signals(stop: threading.Event) -> Callable[[], None]:
    """SIGINT and SIGTERM set ``stop`` (the loop and every wait of the main thread check it); a second
    SIGINT raises ``KeyboardInterrupt`` at once. Returns the function that puts the old handlers back.
    Only the main thread can own signal handlers: elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def handler(signum: int, frame: Any) -> None:
        _SIGNALLED.set()
        if signum == signal.SIGINT and stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    old = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    return lambda: [signal.signal(sig, h) for sig, h in old.items()]


_LEARNER_THREADS: weakref.WeakSet = weakref.WeakSet()
_SIGNALLED = threading.Event()  # a run's SIGINT/SIGTERM handler ran in this process


def stopped_by_signal() -> bool:
    """Whether a run in this process was stopped by SIGINT or SIGTERM."""
    return _SIGNALLED.is_set()


def learner_busy() -> bool:
    """Whether a stopped run left a learner call running (a compile or an update it did not wait for)."""
    return any(t.busy for t in _LEARNER_THREADS)


class LearnerThread:
    """Runs the learner's calls in one dedicated daemon thread, in order, so that the main thread stays
    free to notice a stop during a long first compile or a slow update.

    ``call(stop, fn, *args)`` returns ``fn(*args)`` or raises :class:`StopRequested` once ``stop`` is set,
    without waiting for ``fn``: the call goes on in the background (``busy``) and its result is dropped.
    The caller keeps its last completed state (valid unless the call donated it: see ``Trainer``).
    ``submit`` queues a call and returns its ``Future`` at once. MLX keeps a default stream per thread,
    so the thread makes its own.
    """

    _POLL_S = 0.05

    def __init__(self, platform: str, name: str = "learner"):
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._pending = 0
        self._thread = threading.Thread(target=self._loop, args=(platform,), name=name, daemon=True)
        self._thread.start()
        _LEARNER_THREADS.add(self)

    @property
    def busy(self) -> bool:
        with self._lock:
            return self._pending > 0

    def _loop(self, platform: str) -> None:
        if platform == "mlx":
            import mlx.core as mx

            mx.set_default_stream(mx.new_stream(mx.default_device()))
        try:
            while True:
                job = self._jobs.get()
                if job is None:
                    return
                fn, args, future = job
                error: BaseException | None = None
                try:
                    result = fn(*args)
                except BaseException as e:  # handed to whoever waits on the future
                    error = e
                with self._lock:  # not busy once the caller can see the result
                    self._pending -= 1
                if error is None:
                    future.set_result(result)
                else:
                    future.set_exception(error)
        finally:
            end_thread()

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        future: Future = Future()
        with self._lock:
            self._pending += 1
        self._jobs.put((fn, args, future))
        return future

    def call(self, stop: threading.Event, fn: Callable[..., Any], *args: Any, grace_s: float = 0.0) -> Any:
        """``fn(*args)`` in the thread; after a stop, waits ``grace_s`` more for it to finish."""
        if stop.is_set():
            raise StopRequested("stop requested before a learner call")
        return wait_result(self.submit(fn, *args), stop, grace_s)

    def close(self) -> None:
        """Ends the thread after the calls queued so far; waits for that unless a call is still running
        (a stopped run does not wait for an abandoned update)."""
        self._jobs.put(None)
        if not self.busy:
            self._thread.join(timeout=60)


def wait_result(future: Future, stop: threading.Event, grace_s: float = 0.0) -> Any:
    """``future.result()``, or :class:`StopRequested` once ``stop`` is set and ``grace_s`` more seconds have
    passed without a result (the call is then not waited for)."""
    while True:
        try:
            return future.result(timeout=LearnerThread._POLL_S)
        except FutureTimeout:
            if stop.is_set():
                break
    try:
        return future.result(timeout=grace_s)
    except FutureTimeout:
        raise StopRequested("stop requested during a learner call (left running in the background)") from None


class _AsyncEvaluator:
    """Deterministic evaluations in a background thread on a snapshot of the weights, so lock-step
    workers are not held up. ``eval/wall_s`` is when the snapshot was taken (the training time that
    produced the policy); ``eval/done_wall_s`` when its evaluation finished.

    At most one evaluation waits behind the running one: a newer snapshot replaces a waiting one (an
    evaluation slower than ``--eval_every`` would otherwise queue without bound and hold the end of
    the run for minutes); ``skipped`` counts the replaced ones. ``close(cancel=True)`` (an interrupted
    run) drops the waiting one.
    """

    def __init__(self, trainer: Trainer, stop: threading.Event | None = None):
        """``stop``: when set, the running evaluation ends at its next env step (its result is dropped)."""
        from concurrent.futures import ThreadPoolExecutor

        self._trainer, self._stop = trainer, stop
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="eval")
        self._futures: list[Any] = []
        self.skipped = 0

    def submit(self, weights: dict, counters: dict[str, int], wall_s: float) -> None:
        if self._futures and self._futures[-1].cancel():  # still waiting: replace it with the newer snapshot
            self._futures.pop()
            self.skipped += 1
            log.warning("evaluation at an earlier step skipped: evaluations are slower than --eval_every "
                        "(%d skipped so far)", self.skipped)
        self._futures.append(self._pool.submit(self._run, weights, counters, wall_s))

    def _run(self, weights: dict, counters: dict[str, int], wall_s: float) -> dict[str, float]:
        tr = self._trainer
        result = tr.evaluate(weights, seed=counters["updates"], stop=self._stop)
        result.update({"eval/wall_s": wall_s, "eval/done_wall_s": time.time() - tr.t0,
                       "eval/skipped": float(self.skipped)})
        tr.logger.log(counters["env_steps"], result)
        return result

    def close(self, cancel: bool = False) -> dict[str, float]:
        """Waits for the running evaluation (and the waiting one unless ``cancel``; a stopped run's
        evaluation ends at its next step); returns the newest finished result ({} if none finished)."""
        self._pool.shutdown(wait=True, cancel_futures=cancel)
        done = [f for f in self._futures if not f.cancelled() and not isinstance(f.exception(), StopRequested)]
        return done[-1].result() if done else {}


class _Prefetcher:
    """Runs ``produce()`` in a thread, one item ahead, so collection, sampling and the host-to-device
    copy overlap with the learner's update. Errors surface in the learner thread.

    ``inline`` (serial mode): ``produce`` runs in the caller's thread instead, so a serial run is one
    deterministic sequence of env steps, samples, updates and weight publications; in a thread the
    next batch's env steps would race the publication of the weights they should use.
    """

    def __init__(self, produce: Any, depth: int = 1, inline: bool = False):
        self._produce = produce
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._thread = None if inline else threading.Thread(target=self._loop, name="prefetch", daemon=True)
        if self._thread is not None:
            self._thread.start()

    def _loop(self) -> None:
        try:
            while not self._stop.is_set():
                item = self._produce(self._stop)
                if item is None:
                    continue
                while not self._stop.is_set():
                    try:
                        self._queue.put(item, timeout=0.2)
                        break
                    except queue.Full:
                        continue
        except BaseException as e:  # surfaced to the learner thread (unless we are stopping)
            if not self._stop.is_set():
                self._queue.put(e)
        finally:
            end_thread()

    def get(self, stop: threading.Event | None = None) -> tuple[dict, dict]:
        """The next item; raises :class:`StopRequested` when ``stop`` is set while waiting for it."""
        if self._thread is None:
            item = self._produce(self._stop)
            if item is None:
                raise RuntimeError("the batch source was stopped")
            return item
        while True:
            try:
                item = self._queue.get(timeout=0.1)
            except queue.Empty:
                if stop is not None and stop.is_set():
                    raise StopRequested("stop requested while waiting for a batch") from None
                if not self._thread.is_alive():
                    raise RuntimeError("prefetch thread stopped") from None
                continue
            if isinstance(item, BaseException):
                raise item
            return item

    def stop(self) -> None:
        """Asks the thread to stop; it exits once the pool closes (a pending collect then raises)."""
        self._stop.set()

    def join(self) -> None:
        if self._thread is not None:
            self._thread.join(timeout=10)


class _TrajectorySource:
    """On-policy: one slot per worker (lock-step) or the next ready slots (async) per update."""

    def __init__(self, pool: Any, xp: Any, reward_terms: tuple[str, ...]):
        self._pool, self._xp, self._terms = pool, xp, reward_terms

    def produce(self, stop: threading.Event) -> tuple[dict, dict]:
        batch, info = self._pool.collect(timeout=600.0)
        t0 = time.perf_counter()
        out = {k: self._xp.from_numpy(batch[k]) for k in TRAJECTORY_FIELDS if k in batch}
        stats = _batch_stats(batch, self._terms)
        stats["scalars"].update({"perf/collect_wait_s": info["wait_s"], "perf/collect_copy_s": info["copy_s"],
                                 "perf/to_device_s": time.perf_counter() - t0})
        stats["policy_version"] = np.asarray(batch["policy_version"])
        stats["transitions"] = int(batch["reward"].size)
        return out, stats

    def advance(self, counters: dict[str, int], stats: dict) -> bool:
        lag = counters["version"] - stats["policy_version"]
        stats["scalars"].update({"perf/policy_lag_mean": float(lag.mean()), "perf/policy_lag_max": float(lag.max())})
        counters["env_steps"] += stats["transitions"]
        counters["episodes"] += stats["episodes"]
        return True  # every update publishes

    def pool_scalars(self) -> dict[str, float]:
        return _worker_scalars(self._pool.stats())

    def checkpoint_meta(self) -> None:
        """Nothing to add to a checkpoint: slots are collected afresh after a restart."""
        return None

    def stop(self) -> None:
        """Nothing to flush."""


class _ReplaySource:
    """Off-policy: workers fill the replay ring on their own; the learner samples [U, B] batches,
    holding the update-to-data ratio at ``utd`` gradient steps per env step, and publishes weights
    every ``publish_every`` gradient steps.

    * Warm-up: no gradient step before the buffer holds ``max(learning_starts, batch_size)``
      transitions. While waiting, ``produce`` hands the loop an empty batch (``{}``, a no-op for the
      learner) every ``_TICK_S`` seconds, so the loop keeps logging, evaluating and checking its
      env-step budget: a run whose ``total_steps`` is smaller than ``learning_starts`` ends cleanly
      instead of blocking until the ring fills.
    * The ratio counts env steps from the moment learning starts (as FastTD3 / SB3 do): counted from
      step 0, the first call would owe ``utd * learning_starts`` gradient steps at once, a burst
      on the small initial buffer.
    * The ratio is an upper bound. With ``hold_window`` (``--utd_mode=hold``) it is also held from
      below: the pool's env-step limit follows the learner, at ``learn_start + (gradient steps + U) /
      utd + hold_window`` (never past the run's ``total_steps``, never lowered), so workers pause when
      the learner falls more than the window behind and a slow learner gets the same gradient steps per
      env step as a fast one. The limit always covers the data the next call waits for, so paused
      workers never starve the loop. During warm-up it lets the buffer fill to ``learning_starts`` plus
      the window. Without it (``free``) workers never wait for the learner, and one slower than ``utd``
      x the env rate runs below the ratio. ``perf/utd`` logs the ratio reached.
    * Batch ``k`` of the run (``k`` = the update counter) is sampled with a generator seeded by
      ``(seed, k)``, and checkpoints record the ratio's bookkeeping, so a resumed run samples and
      paces exactly as an uninterrupted one (a batch the prefetcher drew but the loop never used is
      drawn again after the restart).
    * With a device mirror (``mirror``, :class:`~unilab_jax.device_replay.DeviceReplay`): each call first
      copies the newly committed rows to the accelerator, then draws the [U, B] row indices on the host
      (same seeded generator) and gathers the minibatch on the device.
    * With a persistent store (``--replay_dir``): before sampling, the rows the workers committed
      since the last call are copied to the store (:class:`RingSpiller`, once each); minibatches mix
      the rings (``hot_fraction``) and the disk (:class:`TieredSampler`); a checkpoint first commits
      everything received so far (the store's cursor goes into its record). After ``--resume`` the
      rings start empty and the disk tier alone can start learning at once, where the bookkeeping
      left off. Without a store, a resumed run warms up again and counts the ratio afresh.
    * With prior data (``prior``, from an algorithm's ``prior_dir``: RLPD), every minibatch is composed
      of online rows drawn as above and ``prior_fraction`` of rows drawn uniformly from the prior data
      (``core.rlpd.compose``; symmetric sampling at 0.5). The warm-up and the ratio count online data only.
    """

    _TICK_S = 0.25  # seconds between no-op items while the ring warms up
    _STOP_WAIT_S = 5.0  # how long stop() waits for a sample in flight
    _RNG_TAG = 0x5A4D  # keeps the sampling stream apart from other streams derived from the run seed

    def __init__(self, pool: Any, xp: Any, cfg: Any, counters: dict[str, int], seed: int, store: Any = None,
                 hot_fraction: float = 0.5, saved: dict[str, Any] | None = None, mirror: Any = None, *,
                 total_steps: int, hold_window: int | None = None, prior: dict[str, np.ndarray] | None = None):
        self._pool, self._xp, self._cfg, self._mirror = pool, xp, cfg, mirror
        # Prior data (RLPD): each minibatch is (online, prior) rows as core.rlpd.symmetric_split says.
        self._prior = prior
        self._rows = (rlpd.symmetric_split(cfg.batch_size, cfg.prior_fraction) if prior is not None
                      else (cfg.batch_size, 0))
        self._seed = seed % 2**32
        self._steps0 = counters["env_steps"]  # env steps before this process (resume)
        self._budget = max(int(total_steps) - self._steps0, 0)  # pool env steps this process may take
        self._window, self._allowed = hold_window, 0  # ratio holding: window, pool step limit set so far
        self._updates0 = counters["updates"]  # batches used before this process: the next batch's RNG index
        saved = saved or {}
        self._learn_start: int | None = saved.get("learn_start")  # run env steps when learning started
        self._grad_steps = int(saved.get("grad_steps", 0))  # gradient steps since then (produced)
        self._since_publish = int(saved.get("since_publish", 0))
        self._produced = self._consumed = 0  # batches made / used by the loop in this process
        self._warm = self._waited = False
        self._need = max(int(cfg.learning_starts), int(cfg.batch_size))
        self._lock = threading.RLock()  # the sampling thread vs checkpoints and shutdown in the main thread
        self._stopped = False
        self._store, self._spiller, self._tiers = store, None, None
        if store is not None:
            from unilab_jax.runtime.replay_store import RingSpiller, TieredSampler

            self._spiller = RingSpiller(pool.buffer, store)
            self._tiers = TieredSampler(pool.replay_size, lambda n, rng: pool.sample(n, rng, serial_steps=0), store,
                                        hot_fraction, replay_fields(pool.spec))
        capacity = pool.num_workers * pool.buffer.capacity
        if self._need > capacity:
            raise ValueError(f"learning_starts/batch_size ({self._need}) exceed the replay capacity ({capacity} "
                             f"transitions over {pool.num_workers} workers): raise replay_capacity")
        if self._window is not None:
            self._hold(self._need + self._window)

    def _env_steps(self) -> int:
        return self._steps0 + self._pool.env_steps()

    def _hold(self, limit: int) -> None:
        """Raises the pool's env-step limit (pool steps) to ``limit``, capped by the run's budget."""
        limit = min(max(limit, self._allowed), self._budget)
        if limit != self._allowed:
            self._allowed = limit
            self._pool.set_step_limit(limit)

    def _sampleable(self) -> int:
        hot = self._pool.replay_size()
        return hot if self._store is None else max(hot, self._store.size)

    def _wait_tick(self) -> None:
        """One short wait for data: serial mode steps the in-process workers, process mode sleeps
        (and notices a dead worker instead of spinning forever)."""
        if self._pool.serial:
            if self._pool.pump(1) == 0:
                raise RuntimeError("serial replay workers cannot step (no weights published?)")
        else:
            self._pool._maybe_check_workers()
            time.sleep(0.002)

    def produce(self, stop: threading.Event) -> tuple[dict, dict] | None:
        cfg, pool = self._cfg, self._pool
        u, (b, b_prior) = cfg.updates_per_call, self._rows
        noop = {}, {"scalars": {}, "episodes": 0, "noop": True}
        if not self._warm:
            t_end = time.monotonic() + self._TICK_S
            while self._sampleable() < self._need:
                self._waited = True
                if stop.is_set():
                    return None
                if time.monotonic() >= t_end:
                    return noop
                if self._window is not None and pool.step_limit_reached():  # a worker's ring wrapped: go on
                    self._hold(pool.env_steps() + self._window)
                self._wait_tick()
            self._warm = True
            if self._learn_start is None or self._waited:  # (re)starting from a buffer that had to fill
                self._learn_start, self._grad_steps = self._env_steps(), 0
        if self._window is not None:  # let the workers bring this call's data, and the window beyond it
            self._hold(self._learn_start - self._steps0 + math.ceil((self._grad_steps + u) / cfg.utd) + self._window)
        # Hold the update-to-data ratio: wait for data rather than over-train on a small buffer.
        t0 = time.perf_counter()
        while self._grad_steps + u > cfg.utd * (self._env_steps() - self._learn_start):
            if stop.is_set():
                return None
            if pool.env_steps() >= self._budget:  # capped workers will not bring the data: let the loop end
                return noop
            self._wait_tick()
        t1 = time.perf_counter()
        rng = np.random.default_rng([self._seed, self._RNG_TAG, self._updates0 + self._produced])
        with self._lock:
            if self._stopped:
                return None
            scalars = {}
            if self._mirror is not None:
                pool.before_sample()
                scalars["perf/replay_upload_rows"] = float(self._mirror.sync())
                out = self._mirror.gather(self._mirror.sample(u * b, rng).reshape(u, b))
            else:
                if self._store is None:
                    batch = pool.sample(u * b, rng)
                else:
                    pool.pump(1)  # serial mode: the env step pool.sample takes on the ring-only path
                    self._spiller.spill()
                    batch = self._tiers.sample(u, b, rng)
                out = {k: self._xp.from_numpy(batch[k].reshape(u, b, *batch[k].shape[1:]))
                       for k in replay_fields(self._pool.spec)}
            if b_prior:  # the prior data holds fields.prior_fields only: the task's others (``source``) are left out
                idx = rng.integers(0, len(self._prior["reward"]), size=u * b_prior)
                out = rlpd.compose({k: out[k] for k in self._prior},
                                   {k: self._xp.from_numpy(v[idx].reshape(u, b_prior, *v.shape[1:]))
                                    for k, v in self._prior.items()})
                scalars["perf/prior_rows"] = float(b_prior)
        self._grad_steps += u
        self._produced += 1
        scalars.update({"perf/utd_wait_s": t1 - t0, "perf/sample_s": time.perf_counter() - t1})
        return out, {"scalars": scalars, "episodes": 0}

    def advance(self, counters: dict[str, int], stats: dict) -> bool:
        counters["env_steps"] = self._env_steps()
        if stats.get("noop"):  # warm-up tick: no gradient step happened, nothing to publish
            counters["updates"] -= 1
            return False
        self._consumed += 1
        learned_on = max(self._env_steps() - (self._learn_start or 0), 1)
        stats["scalars"].update({"perf/utd": self._grad_steps / learned_on, "perf/utd_target": self._cfg.utd})
        self._since_publish += self._cfg.updates_per_call
        if self._since_publish >= self._cfg.publish_every:
            self._since_publish = 0
            return True
        return False

    def _persist(self) -> None:
        """Copies every committed ring row to the store and commits them (the rings must be open)."""
        with self._lock:
            if self._store is not None and not self._stopped:
                self._spiller.spill()
                self._store.flush()

    def checkpoint_meta(self) -> dict[str, Any]:
        """The sampling bookkeeping as of the batches the loop has used (not the one prefetched), and
        the store's cursor after committing everything received so far."""
        self._persist()
        in_flight = self._produced - self._consumed
        meta: dict[str, Any] = {"learn_start": self._learn_start, "since_publish": self._since_publish,
                                "grad_steps": max(self._grad_steps - in_flight * self._cfg.updates_per_call, 0)}
        if self._store is not None:
            meta.update({"store_dir": self._store.directory, "store_committed": self._store.committed,
                         "store_size": self._store.size, "spill_lost": self._spiller.lost})
        return meta

    def stop(self) -> None:
        """Final commit to the store, then no more access to the rings (the pool closes next). A
        failing commit is logged, not raised: the checkpoint that follows matters more. Waits at most
        ``_STOP_WAIT_S`` for a sample in flight (a first device-mirror call compiles), then gives up."""
        if not self._lock.acquire(timeout=self._STOP_WAIT_S):
            log.warning("replay: a sample was still running after %.0f s; stopping without the final commit",
                        self._STOP_WAIT_S)
            self._stopped = True
            return
        try:
            self._persist()
        except Exception:  # a full disk, say: still close the pool and write the checkpoint
            log.exception("replay store: the final commit failed; the last chunk is lost")
        finally:
            self._stopped = True
            self._lock.release()

    def pool_scalars(self) -> dict[str, float]:
        st = self._pool.stats()
        hot = float(st.get("replay_size", 0))
        # Replay workers wait only for the first weights and at the step limit: the pause of a held ratio.
        out = {"replay/size": hot, "perf/workers_paused_s": st["worker_wait_s"], **_worker_scalars(st)}
        out.update({f"ray/{k}": v for k, v in st.get("ray", {}).items()})  # Ray rollouts: hosts alive, lost
        if self._store is not None:
            disk = self._store.size
            # Rings and disk overlap (every ring row is written through): distinct rows ~ the larger tier.
            out.update({"replay/size": float(max(hot, disk + self._store.pending)), "replay/size_hot": hot,
                        "replay/size_disk": float(disk), "replay/disk_committed": float(self._store.committed),
                        "replay/disk_gb": self._store.disk_bytes / 1e9, "replay/spill_lost": float(self._spiller.lost)})
        if st["recent_episode_returns"].size:
            out["episode/return"] = st["episode_return_mean"]
            out["episode/length"] = st["episode_length_mean"]
            out["episode/terminated_fraction"] = st["episode_terminated_fraction"]
        out.update({f"reward/{k}": v for k, v in st["reward_terms"].items()})
        out.update({f"episode/{k}": v for k, v in st["episode_metrics"].items()})
        return out


def _worker_scalars(stats: dict[str, Any]) -> dict[str, float]:
    """Worker throughput and where worker time goes (act / task / write / wait fractions)."""
    out = {"perf/worker_env_steps_per_s": stats["env_steps_per_s"],
           "perf/worker_restarts": stats["worker_restarts"], "perf/nonfinite_rows": stats["nonfinite_rows"],
           "perf/interrupted_steps": stats["interrupted_steps"], "perf/workers_waiting": stats["workers_waiting"]}
    out.update({f"perf/worker_{k}_fraction": v for k, v in stats["worker_time_fraction"].items()})
    if stats.get("worker_policy_versions"):  # the oldest weights a worker acts with, beside the newest written
        out["perf/worker_policy_version_min"] = float(min(stats["worker_policy_versions"]))
        out["perf/published_version"] = float(stats["published_version"])
    return out


def _batch_stats(batch: dict[str, np.ndarray], reward_terms: tuple[str, ...]) -> dict[str, Any]:
    done = np.asarray(batch["terminated"], bool) | np.asarray(batch["truncated"], bool)
    scalars: dict[str, float] = {}
    if done.any():
        scalars["episode/return"] = float(np.mean(batch["episode_return"][done]))
        scalars["episode/length"] = float(np.mean(batch["episode_length"][done]))
        scalars["episode/terminated_fraction"] = float(np.mean(np.asarray(batch["terminated"], bool)[done]))
    scalars["reward/step_mean"] = float(np.mean(batch["reward"]))
    for i, name in enumerate(reward_terms):
        scalars[f"reward/{name}"] = float(np.mean(batch["reward_terms"][..., i]))
    return {"episodes": int(done.sum()), "scalars": scalars}
