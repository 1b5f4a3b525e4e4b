"""The training loop on the heterogeneous runtime, for every algorithm: trajectory (on-policy: PPO, APPO and
their variants) and replay (off-policy: SAC, TD3, FastSAC, FlashSAC, RLPD, SAC Flow).

Rollout workers (``runtime/pool.py``, or ``runtime/ray_pool.py`` over Ray nodes) collect into shared memory
while the learner updates: trajectory slots, or per-worker replay rings. The batches come from a source
(``training/sources.py``: ``TrajectorySource``, or ``ReplaySource`` with the update-to-data pacing, the
persistent replay store, prior data and the device mirror); a prefetch thread (``training/threads.py``) pulls
the next batch and moves it to the device while the jitted update of the previous one runs. In lock-step
mode the workers wait for the new weights; in async mode they never wait and the policy lag (learner
version minus the version that produced each transition) is logged. Evaluations and clips run in background
threads (``training/evaluation.py``); checkpoints are written at evaluations, every ``checkpoint_every``
env steps and at the end (``--resume`` continues from the last, with the replay rings kept at an orderly stop:
``training/ring_snapshot.py``); an update with a non-finite loss stops the run (:class:`LearningDiverged`).

Stopping: SIGINT and SIGTERM set a stop flag that every wait of the main thread checks. The learner's
own calls (the update, whose first call compiles, and the weight download) run in a dedicated thread
(:class:`LearnerThread`), so a stop never waits long for them: an update in flight gets
``_STOP_GRACE_S`` to finish (a steady GPU update takes milliseconds), then it is abandoned, the state
saved is the one of the last completed update, and the process leaves the abandoned call behind
(``threads.learner_busy()``). After a stopped run the CLI exits without the interpreter's teardown: it would wait
for an abandoned call, and once (a fresh-clone CI) it aborted (exit -6) in third-party teardown after a
complete summary; everything the run owns is saved and closed by then. Updates donate their input only on
accelerators, where the one call that can outlast the grace is the first compile, before any
donation; on the CPU, where an update can take minutes, nothing is donated.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import math
import os
import threading
import time
from typing import Any

import numpy as np

import tasks
from unilab_jax import algos, nets, sizing
from unilab_jax import xp as shim
from unilab_jax.checkpoint import Checkpointer
from unilab_jax.fields import prior_fields, replay_fields
from unilab_jax.metrics import MetricLogger, ProgressBar
from unilab_jax.runtime.buffers import transition_layout
from unilab_jax.runtime.pool import WorkerPool
from unilab_jax.runtime.prior import load_prior
from unilab_jax.runtime.replay_store import ReplayStore
from unilab_jax.runtime.ring import StopRequested
from unilab_jax.runtime.spawn import cpu_placement
from unilab_jax.runtime.weights import WeightPublisher
from unilab_jax.runtime.worker import PREFETCH_MIN_BYTES
from unilab_jax.training import compile_cache, ring_snapshot
from unilab_jax.training.evaluation import AsyncEvaluator, ClipRecorder, evaluate_policy
from unilab_jax.training.profiling import ProfileWindow
from unilab_jax.training.run_config import RunConfig
from unilab_jax.training.sources import DeferredBatch, ReplaySource, TrajectorySource, batch_layout
from unilab_jax.training.threads import LearnerThread, Prefetcher, UpdatePipeline, stop_on_signals
from unilab_jax.xp import tree_leaves

log = logging.getLogger(__name__)


def _learner_platform(platform: str) -> Any:
    """Backend used to convert numpy batches for the learner."""
    return shim.get(platform)


def _device_copy(tree: Any) -> Any:
    """A copy of a tree of JAX arrays in new device buffers (one jitted call, compiled once per structure)."""
    return _copier()(tree)


@functools.cache
def _copier() -> Any:
    import jax
    import jax.numpy as jnp

    return jax.jit(lambda t: jax.tree.map(jnp.copy, t))


def _donated(tree: Any) -> bool:
    """Whether any leaf is a JAX array whose buffer was donated to a computation."""
    return any(getattr(leaf, "is_deleted", lambda: False)() for leaf in tree_leaves(tree))


class Trainer:
    _STOP_GRACE_S = 2.0  # after a stop, how long the loop still waits for the update in flight
    def __init__(self, run: RunConfig, algo_module: Any, algo_config: Any, task_overrides: dict[str, Any],
                 start_time: float | None = None, eval_overrides: dict[str, Any] | None = None):
        """``start_time``: wall clock that ``time/wall_s`` and ``eval/wall_s`` count from (the process
        start when launched from the CLI, so compilation and worker start-up are included; moved back by a resumed
        checkpoint's ``wall_s``, so the clock goes on across a resume).
        ``eval_overrides``: task overrides added for evaluations only (e.g. robot tasks evaluating on
        the robots that answer, ``min_envs``)."""
        self.t0 = time.time() if start_time is None else start_time
        compile_cache.configure(run.compilation_cache, run.platform)
        self.run, self.algo, self.config, self.task_overrides = run, algo_module, algo_config, task_overrides
        self.eval_overrides = {**task_overrides, **(eval_overrides or {})}
        probe = tasks.make(run.task, num_envs=1, seed=run.seed, overrides=task_overrides)
        self.spec = probe.spec
        probe.close()
        self.xp = _learner_platform(run.platform)
        self.learner = algos.make_learner(algo_module, run.platform, algo_config, self.spec)
        self.parallel = None  # the DataParallel learner of --devices > 1
        if run.devices != "1":
            from unilab_jax.training import sharding  # imports jax: only when asked for (MLX-only installs)

            self.parallel = sharding.for_run(self.learner, run, algo_config, algo_module.BUFFER)
            self.learner = self.parallel or self.learner
        self.batch_xp = self.parallel or self.xp  # what the batch sources place host arrays with (from_numpy)
        self.logger = MetricLogger(run.logdir, run.wandb_project,
                                   {"run": dataclasses.asdict(run), "algo": dataclasses.asdict(algo_config),
                                    "task_overrides": dict(task_overrides)} if run.wandb_project else None)
        self.ckpt_dir = os.path.join(os.path.abspath(run.logdir), "checkpoints")
        self._stop = threading.Event()
        self._precompiling: threading.Thread | None = None  # the update's compile, ahead of the first call
        self._resumed_meta: dict[str, Any] = {}  # meta of the checkpoint this run resumed from

    # -- state -----------------------------------------------------------------------------------
    def _init_state(self) -> tuple[Any, dict[str, int]]:
        state = self.learner.init(self.xp.random.key(self.run.seed))
        counters = {"env_steps": 0, "updates": 0, "version": 0, "episodes": 0}
        if self.run.resume:

            ckpt = Checkpointer(self.ckpt_dir)
            for name in ckpt.remove_unfinished_saves():  # a save the previous run was killed in the middle of
                log.warning("--resume: removed %s, an unfinished checkpoint save", os.path.join(self.ckpt_dir, name))
            if ckpt.latest_step() is None:
                raise FileNotFoundError(f"--resume: no checkpoint under {self.ckpt_dir}")
            state, meta = ckpt.restore(state, lambda a, like: self.xp.from_numpy(a))
            ckpt.close()
            if self.parallel is not None:
                state = self.parallel.place(state)
            self._resumed_meta = meta
            counters = {k: int(v) for k, v in meta["counters"].items()}
            # The clock runs on across a resume: time/wall_s and eval/wall_s continue from the checkpoint's (this
            # process's start-up counted again), so a run split over several processes is timed as one.
            self.t0 -= float(meta.get("wall_s", 0.0))
            if meta.get("task") != self.run.task or meta.get("algo") != self.run.algo:
                raise ValueError(f"--resume: checkpoint is {meta.get('algo')}/{meta.get('task')}, "
                                 f"not {self.run.algo}/{self.run.task}")
        return state, counters

    def _meta(self, counters: dict[str, int], source: Any = None) -> dict[str, Any]:
        meta = {"counters": dict(counters), "wall_s": time.time() - self.t0, "algo": self.run.algo,
                "task": self.run.task, "run": dataclasses.asdict(self.run), "config": dataclasses.asdict(self.config),
                "task_overrides": {k: str(v) for k, v in self.task_overrides.items()}}
        replay = source.checkpoint_meta() if source is not None else None
        if replay is not None:
            meta["replay"] = replay
        return meta

    def _device_replay(self, pool: Any) -> Any:
        """The accelerator-side replay mirror, or None (see ``RunConfig.replay_on_device``)."""
        mode = self.run.replay_on_device  # one of auto/on/off (RunConfig checks it)
        if mode == "off" or self.run.platform != "jax" or self.run.replay_dir:
            if mode == "on":
                raise ValueError("replay_on_device=on needs the jax platform and no replay_dir")
            return None
        import jax  # here only: an MLX-only install never imports it

        if mode == "auto" and jax.default_backend() == "cpu":
            return None
        from unilab_jax.training.device_replay import DeviceReplay

        return DeviceReplay(pool.buffer, replay_fields(self.spec), self.parallel)

    def _row_layout(self, names: tuple[str, ...]) -> dict[str, Any]:
        """The (shape, dtype) of the transition fields ``names`` for this run's task and algorithm."""

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
        directory = self.config.prior_dir if algos.info(self.algo).prior_data else ""
        if not directory:
            return None

        prior = load_prior(directory, self._row_layout(prior_fields(self.spec)))
        log.info("prior data: %d transitions from %s", len(prior["reward"]), directory)
        return prior

    # -- evaluation ------------------------------------------------------------------------------
    def evaluation_job(self, weights: dict, seed: int) -> dict[str, Any]:
        """The arguments of ``evaluation.evaluate_policy`` for this run's evaluation of ``weights``: the
        deterministic policy, one full episode in each of ``eval_envs`` environments (or as many as the task could
        build, e.g. the robots that answer)."""
        return {"algo": self.algo.__name__, "weights": weights, "task": self.run.task,
                "overrides": self.eval_overrides, "num_envs": self.run.eval_envs, "seed": seed}

    def evaluate(self, weights: dict, seed: int, stop: threading.Event | None = None) -> dict[str, float]:
        """This run's evaluation of ``weights`` in this process (``evaluation.evaluate_policy``); raises
        :class:`StopRequested` when ``stop`` is set before it ends."""
        return evaluate_policy(**self.evaluation_job(weights, seed), stop=stop)

    def _eval_in_process(self) -> bool:
        """Whether evaluations run in a process of their own (``RunConfig.eval_process``)."""
        mode = self.run.eval_process  # one of auto/on/off (RunConfig checks it)
        if mode != "auto":
            return mode == "on"
        return not self.run.serial and not sizing.learner_on_cpu(self.run.platform)

    # -- the loop ----------------------------------------------------------------------------------
    def train(self) -> dict[str, Any]:

        run, cfg, stop = self.run, self.config, self._stop
        evaluator = AsyncEvaluator(self, stop, in_process=self._eval_in_process())
        learner = LearnerThread(run.platform)
        state, counters = self._init_state()
        t_start = self.t0  # after _init_state: a resumed run's clock goes on from its checkpoint's
        log.info("learner state ready %.1f s after the start", time.time() - t_start)
        weights = nets.to_numpy(self.learner.weights(state))
        clips = None
        if run.video_every:

            clips = ClipRecorder(self, run.video_every, counters["env_steps"])
        replay = self.algo.BUFFER == "replay"
        keep_rings = replay and run.keep_replay and not run.replay_dir and not run.ray_address
        hold_window = self._hold_window(cfg) if replay else None
        # Opened before any worker starts or checkpoint is written, so a refused store changes nothing.
        store = self._open_replay_store() if replay else None
        prior = self._load_prior() if replay else None
        if replay:  # from here on, while the workers start and the rings fill
            self._precompiling = self._start_precompile(state, prior)
        pool_kwargs = dict(task_name=run.task, task_overrides=self.task_overrides, num_workers=run.num_workers,
                           envs_per_worker=run.envs_per_worker, seed=run.seed + counters["updates"],
                           algo_module=self.algo.__name__, weight_template=weights,
                           horizon=cfg.horizon, serial=run.serial,
                           replay_capacity=max(cfg.replay_capacity // run.num_workers, 1)
                           if replay else 0, replay_row_sums=bool(run.replay_dir),
                           max_env_steps=max(run.total_steps - counters["env_steps"], 0) if replay else None)
        if run.ray_address:
            from unilab_jax.runtime.ray_pool import RayPool  # Ray is imported only for --ray_address

            pool = RayPool(run.ray_address, workers_per_host=run.ray_workers_per_host or None, **pool_kwargs)
        else:
            pool = WorkerPool(**pool_kwargs, worker_cpus=cpu_placement(run.num_workers, run.pin_cpus)
                              if run.pin_cpus >= 0 and not run.serial else None)
        if keep_rings and run.resume:  # before any worker starts
            ring_snapshot.resume(pool.buffer, run.logdir, run.task, counters["env_steps"])
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
        interrupted = orderly = False  # orderly: the loop ended, or a stop ended it (not an error)
        diverged: LearningDiverged | None = None
        prefetch: Prefetcher | None = None
        pipe: UpdatePipeline | None = None
        source: ReplaySource | TrajectorySource | None = None
        progress = ProgressBar(run.total_steps, counters["env_steps"])
        profile = ProfileWindow(run)
        try:
            pool.start(stop=stop.is_set)
            log.info("%d workers started %.1f s after the start", run.num_workers, time.time() - t_start)
            # The source before the first weights: replay workers wait for them, so a held run's step
            # limit is in place before any env step.
            source = (ReplaySource(pool, self.batch_xp, cfg, counters, run.seed, store, run.replay_hot_fraction,
                                    self._resumed_meta.get("replay"), self._device_replay(pool),
                                    total_steps=run.total_steps, hold_window=hold_window, prior=prior)
                      if replay else TrajectorySource(pool, self.batch_xp, self.spec.reward_terms))
            pool.publish(weights, counters["version"])
            prefetch = Prefetcher(source.produce, inline=run.serial)
            # Off-policy runs queue the next call before this one's results are read, so the device never waits
            # for the loop's host work (threads.UpdatePipeline); replay batches need no new weights. Trajectory
            # batches are collected with the newest weights, and serial runs are one deterministic sequence:
            # one call at a time.
            pipe = UpdatePipeline(learner, self._dispatch, self._fetch, state,
                                  depth=2 if replay and not run.serial else 1, fetch_on_thread=run.platform == "mlx")
            queued: list[tuple[dict, float]] = []  # each queued call's batch stats and prefetch wait
            t_last, steps_last = time.time(), counters["env_steps"]

            def finish() -> None:
                """Reads the oldest queued call's results: counts, checks, publishes and logs them."""
                nonlocal t_last, steps_last
                scalars, update_s, fetch_s, host = pipe.result(stop, self._STOP_GRACE_S)
                stats, wait_s = queued.pop(0)
                t_publish = time.perf_counter()
                counters["updates"] += 1
                publish = source.advance(counters, stats)
                bad = sorted(k for k, v in scalars.items() if not math.isfinite(v))
                if bad:  # before the weights reach the workers or a checkpoint
                    raise LearningDiverged(bad, counters, ckpt.latest_step())
                if publish:
                    counters["version"] += 1
                    (publisher.submit if publisher is not None else pool.publish)(host, counters["version"])
                now = time.time()
                scalars.update({"perf/learner_wait_s": wait_s, "perf/update_s": update_s, "perf/fetch_s": fetch_s,
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

            while counters["env_steps"] < run.total_steps and not stop.is_set():
                profile.step(counters["updates"])
                t_wait = time.perf_counter()
                batch, stats = prefetch.get(stop)
                pipe.submit(batch)
                queued.append((stats, time.perf_counter() - t_wait))
                if pipe.full:
                    finish()
                steps = counters["env_steps"]
                evaluate = next_eval is not None and steps >= next_eval
                save = next_ckpt is not None and steps >= next_ckpt
                clip = clips is not None and clips.due(steps)
                if not (evaluate or save or clip):
                    continue
                while queued:  # the state they read is the newest one, its counters counted
                    finish()
                state = pipe.state
                if evaluate:
                    evaluator.submit(learner.call(stop, self._numpy_weights, state), dict(counters),
                                     time.time() - t_start)
                    evaluated_at = counters["env_steps"]
                    next_eval += run.eval_every
                    ckpt.save(counters["env_steps"], state, self._meta(counters, source))
                if clip:
                    clips.submit(learner.call(stop, self._numpy_weights, state), counters["env_steps"])
                if save:
                    ckpt.save(counters["env_steps"], state, self._meta(counters, source))
                    next_ckpt += run.checkpoint_every
            while queued and not stop.is_set():
                finish()
            orderly = True
        except (KeyboardInterrupt, StopRequested):
            interrupted = orderly = True
        except LearningDiverged as e:
            diverged = e
        finally:
            if pipe is not None:
                state = pipe.cancel()
            progress.close()
            profile.close()
            if prefetch is not None:
                prefetch.stop()
            if source is not None:
                source.stop()  # the last spill to disk, while the rings still exist
            if publisher is not None:
                publisher.close()
            (pool.stop if keep_rings and orderly else pool.close)()  # kept rings: read after the last checkpoint
            if prefetch is not None:
                prefetch.join()
            try:
                if diverged is None:  # a diverged state is not saved: the last checkpoint stands
                    self._final_save(ckpt, counters, state, source)
                ckpt.close()
                if keep_rings and orderly:
                    ring_snapshot.keep(pool.buffer, run.logdir, run.task, counters["env_steps"])
            finally:
                pool.close()
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
        if evaluator.interrupted or evaluator.lost:  # logged as they happened; the summary says why eval/* is older
            summary["eval/dropped"] = evaluator.interrupted + evaluator.lost
        if diverged is not None:
            summary["diverged"] = str(diverged)
        shortfall = None if interrupted else self._shortfall(counters, source)
        if shortfall is not None:
            summary["warning"] = shortfall
            log.warning("%s", shortfall)
        with open(os.path.join(run.logdir, "summary.json"), "w") as f:
            json.dump(summary, f, indent=2)
        if diverged is not None:
            raise diverged
        return summary

    def _shortfall(self, counters: dict[str, int], source: Any) -> str | None:
        """A finished run that made no learner update, or fewer than its algorithm asks: why, else None."""
        if isinstance(source, ReplaySource):
            return source.shortfall(counters["env_steps"])
        if counters["updates"] == 0:
            run = self.run
            batch = self.config.horizon * run.num_workers * run.envs_per_worker
            return (f"no learner update: one update needs a batch of horizon={self.config.horizon} x "
                    f"{run.num_workers * run.envs_per_worker} envs = {batch:,} env steps, and the run took "
                    f"{counters['env_steps']:,}; raise --total_steps")
        return None

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

    def _start_precompile(self, state: Any, prior: dict[str, np.ndarray] | None) -> threading.Thread | None:
        """An off-policy JAX learner (on one device, or the ``DataParallel`` one of several) compiles its update in a
        thread from the start of the run, while the worker pool is built, the workers start and the rings fill
        (``learner.precompile`` for the minibatches ``sources.batch_layout`` describes; ``RunConfig.precompile``): the
        first update waits for it instead of compiling then (14-18 s on the H100 machine, while the workers ran on)."""
        if self.run.platform != "jax" or algos.info(self.algo).family != "off_policy":
            return None
        if self.run.precompile == "off" or (self.run.precompile == "auto" and sizing.learner_on_cpu("jax")):
            return None
        layout = batch_layout(self._row_layout(replay_fields(self.spec)), self.config, prior)

        def work() -> None:
            t0 = time.perf_counter()
            try:
                self.learner.precompile(state, layout)
            except Exception:  # the first update compiles it instead
                log.exception("compiling the update ahead of the first call failed")
                return
            log.info("update compiled ahead of the first call in %.1f s, %.1f s after the start",
                     time.perf_counter() - t0, time.time() - self.t0)

        thread = threading.Thread(target=work, name="precompile", daemon=True)
        thread.start()
        return thread

    def _dispatch(self, state: Any, batch: dict | DeferredBatch) -> tuple[Any, Any]:
        """One learner update, dispatched (a device mirror's batch finished first, on this thread): the new state
        and (metrics, new weights) still on the device. On JAX the weights are copied on the device, so the next
        update, which donates this state on accelerators, can be queued before they reach the host. The first
        waits for the update's compile ahead (``_start_precompile``)."""
        if self._precompiling is not None and (isinstance(batch, DeferredBatch) or batch):
            self._precompiling.join()
            self._precompiling = None
        if isinstance(batch, DeferredBatch):
            batch = batch()
        state, metrics = self.learner.update(state, batch)
        out = (metrics, self.learner.weights(state))
        return state, (_device_copy(out) if self.run.platform == "jax" else out)

    @staticmethod
    def _fetch(out: Any) -> tuple[dict[str, float], dict]:
        """An update's losses as floats and its weights on the host, in one transfer (which waits for the
        update to finish; a transfer per loss cost ~1 ms each in-run)."""
        metrics, weights = nets.to_numpy(out)
        return {f"loss/{k}": float(v) for k, v in metrics.items()}, weights

    def _hold_window(self, cfg: Any) -> int | None:
        """Env steps the replay workers may run ahead of ``utd``; None in "free" mode. The default, four
        learner calls' worth (at least four steps of every env), absorbs the jitter of a learner that
        keeps pace on average."""
        if self.run.utd_mode == "free":  # hold or free, utd_window >= 0: RunConfig checks them
            return None
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
