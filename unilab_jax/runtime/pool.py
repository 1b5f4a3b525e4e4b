"""WorkerPool: the learner's handle on the rollout workers, their buffers and the weight channel.

::

    pool = WorkerPool("cartpole_balance", {}, num_workers=4, envs_per_worker=64, seed=0,
                      algo_module="unilab_jax.algos.ppo.ppo", weight_template=weights, horizon=24)
    pool.start()
    pool.publish(weights, version=0)
    for it in range(...):
        batch, info = pool.collect()          # trajectory buffers: {field: [T, W*M, ...]} numpy
        ...update...
        pool.publish(new_weights, version=it + 1)
    pool.close()

Replay algorithms use ``pool.sample(batch_size, rng)`` and ``pool.replay_size()`` instead of
``collect``. ``serial=True`` builds the same :class:`~unilab_jax.runtime.worker.Worker` objects in
this process and runs their chunks inside ``collect`` / ``sample`` / ``pump``: the same shared-memory
path, deterministic, debuggable with pdb.

Worker processes use the ``spawn`` context, started without re-running the learner's script and with
pinned thread pools (``unilab_jax/runtime/spawn.py``). ``close()`` raises a shared stop flag, joins the
workers (SIGKILL after a grace period) and unlinks every segment; it is idempotent and also runs from a
``weakref.finalize`` at exit. ``stop()`` is its first half: the workers end, the segments stay readable.
``stats()`` reads the workers' counters (``unilab_jax/runtime/pool_stats.py``).

Worker faults are handled while the learner waits on the pool (``collect``, ``sample``,
``wait_replay``: every ``poll`` seconds), in the learner's consumer thread, so the recovery may touch
the consumer side of the rings:

* a worker that raised (status FAILED) raises :class:`WorkerDiedError` with its traceback at once:
  a Python error is most likely deterministic, and respawning it would crash-loop;
* a worker that died without reporting (SIGKILL, the OOM killer, a segfault in native code) is
  respawned with a new seed, up to ``max_restarts`` times over the pool: the slot it was writing
  goes back to its free ring (:meth:`TrajectoryBuffer.reclaim`), uncommitted replay rows are simply
  never published, and a lock-step worker resumes after the last chunk it published, so a
  ``collect`` in progress gets the new process's slot for the current weights;
* a worker whose heartbeat has not moved for ``heartbeat_timeout`` seconds (SIGSTOP, a hang in
  native code) is SIGKILLed (which works on stopped processes) and respawned the same way. Killing
  rather than raising: a stopped or wedged process has no traceback to report and leaves exactly
  the state a killed one does, so the run can go on; a hang that recurs exhausts ``max_restarts``
  and then raises, naming the worker and its pid.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import logging
import multiprocessing as mp
import os
import time
import weakref
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from unilab_jax.runtime.buffers import ReplayBuffer, TrajectoryBuffer, transition_layout
from unilab_jax.runtime.pool_stats import PoolStats
from unilab_jax.runtime.ring import RingTimeout, StopRequested, wait_for
from unilab_jax.runtime.shm import SharedArrays, cleanup_stale
from unilab_jax.runtime.spawn import PoolResources, hidden_main, worker_environment
from unilab_jax.runtime.weights import WeightChannel
from unilab_jax.runtime.worker import (
    CHUNKS,
    FAILED,
    HEARTBEAT,
    NEW,
    PID,
    READY,
    RESUME_VERSION,
    STATUS,
    STEP_LIMIT,
    STEPS,
    VERSION,
    Worker,
    WorkerArgs,
    control_layout,
    init_control,
    read_error,
    worker_main,
)

__all__ = ["WorkerPool", "WorkerDiedError", "load_algo"]

log = logging.getLogger(__name__)


class WorkerDiedError(RuntimeError):
    """A worker process exited or failed; carries its exit code and traceback."""


def load_algo(name: str) -> Any:
    """Imports an algorithm module and checks that it declares what the runtime needs."""
    if name in ("__main__", "__mp_main__"):
        raise ValueError("the algorithm module must be importable by name in the workers, not __main__")
    mod = importlib.import_module(name)
    from unilab_jax.algos.contract import missing as lacking  # what the workers read (RolloutDeclaration)
    missing = lacking(mod)
    if missing:
        raise ValueError(f"algorithm module {name!r} lacks {missing} (see docs/ARCHITECTURE.md)")
    if mod.SYNC not in ("lockstep", "async"):
        raise ValueError(f"{name}.SYNC must be 'lockstep' or 'async', got {mod.SYNC!r}")
    if mod.BUFFER not in ("trajectory", "replay"):
        raise ValueError(f"{name}.BUFFER must be 'trajectory' or 'replay', got {mod.BUFFER!r}")
    return mod



class WorkerPool:
    """Rollout workers + shared-memory buffers + weight channel (see module docstring).

    Args:
      task_name, task_overrides: passed to ``tasks.make`` in every worker (validated here first).
      num_workers, envs_per_worker: W processes with M envs each; worker ``i`` is seeded
        ``seed * 1000 + i``.
      algo_module: import path of the algorithm module (``SYNC``, ``BUFFER``, ``extras``, ``act``).
      weight_template: numpy pytree with the shapes/dtypes of the published weights.
      horizon: T, control steps per trajectory slot (also the lockstep chunk in replay mode).
      slots_per_worker: K trajectory slots per worker.
      replay_capacity: transitions per worker region (replay buffers).
      replay_row_sums: whether replay commits checksum their rows (what a replay store's spiller verifies).
      serial: run the workers in this process.
      wait_timeout: worker-side wait limit for weights / free slots (None: until stopped).
      poll: how often waits check for dead workers, seconds.
      worker_threads: BLAS / OpenMP threads per worker process (1: no oversubscription). Serial
        mode runs with this process's settings.
      max_restarts: respawns allowed over the pool's life for workers that died without a Python
        error or stopped heartbeating; the next such death raises :class:`WorkerDiedError`.
      heartbeat_timeout: seconds without a heartbeat after which a started worker counts as hung
        (None: never). Workers beat every env step and every ``poll`` while waiting, so this only
        has to exceed the slowest single env step or policy call.
      max_env_steps: replay buffers only: workers stop stepping once the pool-wide env-step count
        reaches it (see :meth:`set_step_limit`).
      worker_cpus: per worker, the CPUs it (and the MuJoCo threads it starts) may run on
        (``os.sched_setaffinity`` right after the spawn; ``spawn.cpu_placement``); None: no affinity.
    """

    def __init__(
        self,
        task_name: str,
        task_overrides: Mapping[str, Any] | None = None,
        num_workers: int = 1,
        envs_per_worker: int = 1,
        seed: int = 0,
        algo_module: str = "",
        weight_template: Any = None,
        horizon: int = 32,
        slots_per_worker: int = 2,
        replay_capacity: int = 0,
        serial: bool = False,
        *,
        replay_row_sums: bool = True,
        wait_timeout: float | None = None,
        poll: float = 0.05,
        worker_threads: int = 1,
        max_restarts: int = 3,
        heartbeat_timeout: float | None = 30.0,
        max_env_steps: int | None = None,
        worker_cpus: Sequence[Sequence[int]] | None = None,
    ):
        import tasks

        if num_workers <= 0 or envs_per_worker <= 0 or horizon <= 0:
            raise ValueError("num_workers, envs_per_worker and horizon must be positive")
        if weight_template is None:
            raise ValueError("weight_template (a numpy pytree) is required")
        self.algo = load_algo(algo_module)
        self.sync: str = self.algo.SYNC
        self.buffer_kind: str = self.algo.BUFFER
        if self.buffer_kind == "replay" and replay_capacity <= 0:
            raise ValueError(f"{algo_module} uses a replay buffer: replay_capacity must be positive")
        if self.buffer_kind == "trajectory" and slots_per_worker <= 0:
            raise ValueError("slots_per_worker must be positive")
        overrides = dict(task_overrides or {})
        probe = tasks.make(task_name, 1, seed, overrides)  # fails here, before any worker starts
        self.spec = probe.spec
        probe.close()
        self.task_name, self.task_overrides = task_name, overrides
        self.num_workers, self.envs_per_worker = int(num_workers), int(envs_per_worker)
        self.horizon, self.seed, self.serial = int(horizon), int(seed), bool(serial)
        self.algo_module = algo_module
        self.poll = float(poll)
        self.worker_threads = int(worker_threads)
        self.max_restarts = int(max_restarts)
        self.heartbeat_timeout = None if heartbeat_timeout is None else float(heartbeat_timeout)
        if worker_cpus is not None and len(worker_cpus) != num_workers:
            raise ValueError(f"worker_cpus has {len(worker_cpus)} entries for {num_workers} workers")
        self.worker_cpus = None if worker_cpus is None else [sorted(int(c) for c in cs) for cs in worker_cpus]
        if max_env_steps is not None and self.buffer_kind != "replay":
            raise ValueError("max_env_steps is for replay buffers (trajectory workers are held by their slots)")
        self.fields = transition_layout(self.spec, self.algo.extras(self.spec.action_dim))

        stale = cleanup_stale()  # segments of runs whose creator was killed (kill -9 of the tree)
        if stale:
            log.warning("removed %d stale shared-memory segments of dead runs: %s", len(stale), stale)
        self._res = PoolResources()
        self._finalizer = weakref.finalize(self, self._res.shutdown)
        try:
            n_sums = len(self.spec.reward_terms) + len(self.spec.episode_metrics)
            ctl = SharedArrays.create(control_layout(num_workers, n_sums), tag="ctl")
            self._res.closers.append(ctl)
            self._res.control = ctl
            init_control(ctl)
            self._ctl = ctl
            self.weights = WeightChannel(weight_template)
            self._res.closers.append(self.weights)
            if self.buffer_kind == "trajectory":
                self.buffer: TrajectoryBuffer | ReplayBuffer = TrajectoryBuffer.create(
                    self.fields, num_workers, envs_per_worker, horizon, slots_per_worker)
            else:
                self.buffer = ReplayBuffer.create(self.fields, num_workers, envs_per_worker, replay_capacity,
                                                  row_sums=replay_row_sums)
            self._res.closers.append(self.buffer)
        except BaseException:
            self._res.shutdown()
            raise
        self._args = [
            WorkerArgs(
                worker_id=i, task_name=task_name, task_overrides=tuple(sorted(overrides.items())),
                envs_per_worker=self.envs_per_worker, seed=self.seed, algo_module=algo_module,
                sync=self.sync, buffer_kind=self.buffer_kind, horizon=self.horizon,
                buffer_handle=self.buffer.handle, weights_handle=self.weights.handle,
                control_handle=ctl.handle, parent_pid=os.getpid(), wait_timeout=wait_timeout,
            )
            for i in range(num_workers)
        ]
        self._ctx = mp.get_context("spawn")
        self._procs: list[Any] = [None] * num_workers
        self._serial_workers: list[Worker] = []
        self._started = False
        self._stats = PoolStats(ctl, self.spec)
        self._last_death_check = 0.0
        self.version = -1
        self._restarts = [0] * num_workers
        self._held: list[set[int]] = [set() for _ in range(num_workers)]  # trajectory slots the learner holds
        self._last_taken_version = [-1] * num_workers  # lockstep: version of the last slot taken per worker
        self._beat = [(0, 0.0)] * num_workers  # (heartbeat word, when it last changed) per worker
        self.set_step_limit(max_env_steps)

    # ---- lifecycle ----------------------------------------------------------------------------
    @property
    def segment_names(self) -> list[str]:
        return [self._ctl.name, self.weights.seg.name, *self.buffer.segment_names]

    def start(self, wait: bool = True, timeout: float = 300.0, stop: Callable[[], bool] | None = None) -> WorkerPool:
        """Starts the workers; with ``wait`` returns once every worker has built its task, or raises
        :class:`StopRequested` as soon as ``stop()`` is true while waiting (a signal during start-up)."""
        if self._res.closed:
            raise RuntimeError("the pool is closed")
        if self._started:
            return self
        self._started = True
        if self.serial:
            for args in self._args:
                w = Worker(args)
                self._serial_workers.append(w)
                self._res.closers.append(w)
        else:
            for i in range(self.num_workers):
                self._spawn(i)
            if wait:
                status = self._ctl["worker"][:, STATUS]

                def check() -> None:
                    if stop is not None and stop():
                        raise StopRequested("stop requested while the workers were starting")
                    self._check_workers()

                wait_for(lambda: True if (status != 0).all() else None, timeout=timeout,
                         check=check, poll=self.poll, what="workers to start")
                self._check_workers()
        self._stats.restart_clock()
        return self

    def _spawn(self, i: int) -> None:
        old = self._procs[i]
        p = self._ctx.Process(target=worker_main, args=(self._args[i],), name=f"unilab-worker-{i}", daemon=True)
        with hidden_main(), worker_environment(self.worker_threads):
            p.start()
        if self.worker_cpus is not None:
            # Before the worker imports anything (seconds): threads it starts later inherit the set.
            with contextlib.suppress(ProcessLookupError):
                os.sched_setaffinity(p.pid, self.worker_cpus[i])
        self._procs[i] = p
        if old in self._res.procs:
            self._res.procs[self._res.procs.index(old)] = p
        else:
            self._res.procs.append(p)
        self._beat[i] = (int(self._ctl["worker"][i, HEARTBEAT]), time.monotonic())

    def stop(self, grace: float = 5.0) -> None:
        """Stops the workers (within ``grace`` s, then SIGKILL) and keeps the segments: what the workers wrote can
        still be read (the replay rings kept at an orderly stop, ``training/ring_snapshot.py``) until :meth:`close`."""
        self._res.stop(grace)

    def close(self, grace: float = 5.0) -> None:
        """Stops the workers (within ``grace`` s, then SIGKILL), unlinks every segment."""
        self._res.shutdown(grace)
        self._finalizer.detach()

    @property
    def closed(self) -> bool:
        return self._res.closed

    def __enter__(self) -> WorkerPool:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _check_workers(self) -> None:
        """Raises :class:`WorkerDiedError` for a failed worker; respawns killed or hung ones."""
        if self._res.stopped:  # the workers were stopped on purpose: none is respawned
            raise RuntimeError("the pool is stopped")
        words = self._ctl["worker"]
        now = time.monotonic()
        for i, p in enumerate(self._procs):
            if p is None:
                continue
            alive = p.is_alive()
            if not alive:
                p.join(0.5)
            if words[i, STATUS] == FAILED:  # read after is_alive: a worker reports before it exits
                raise WorkerDiedError(f"rollout worker {i} (pid {p.pid}) failed:\n{read_error(self._ctl, i)}")
            if not alive:
                self._restart(i, f"exited with code {p.exitcode} without a traceback (killed?)")
                continue
            beat = int(words[i, HEARTBEAT])
            if words[i, STATUS] != READY or beat != self._beat[i][0]:
                self._beat[i] = (beat, now)  # still building its task, or alive
            elif self.heartbeat_timeout is not None and now - self._beat[i][1] > self.heartbeat_timeout:
                silent = now - self._beat[i][1]
                p.kill()
                p.join(5.0)
                self._restart(i, f"sent no heartbeat for {silent:.1f} s (stopped or hung) and was killed")

    def _restart(self, i: int, why: str) -> None:
        """Respawns dead worker ``i`` after making its buffer state consistent (see module docstring)."""
        old = self._procs[i]
        total = sum(self._restarts)
        if total >= self.max_restarts:
            raise WorkerDiedError(f"rollout worker {i} (pid {old.pid}) {why}; the pool has respawned workers "
                                  f"{total} times (max_restarts={self.max_restarts})")
        log.warning("rollout worker %d (pid %d) %s; respawning it (restart %d of %d)", i, old.pid, why,
                    total + 1, self.max_restarts)
        words = self._ctl["worker"]
        if isinstance(self.buffer, TrajectoryBuffer):
            self.buffer.reclaim(i, self._held[i])
            if self.sync == "lockstep":
                versions = [int(self.buffer.slot(i, s)["policy_version"][0, 0]) for s in self.buffer.full[i].pending()]
                words[i, RESUME_VERSION] = max([self._last_taken_version[i], *versions])
        with contextlib.suppress(ValueError):
            old.close()
        self._ctl["error"][i] = 0
        words[i, STATUS] = NEW
        self._restarts[i] += 1
        self._args[i] = dataclasses.replace(self._args[i], restarts=self._restarts[i])
        self._spawn(i)

    def _maybe_check_workers(self) -> None:
        now = time.monotonic()
        if now - self._last_death_check > self.poll:
            self._last_death_check = now
            self._check_workers()

    # ---- weights ------------------------------------------------------------------------------
    def set_step_limit(self, max_env_steps: int | None) -> None:
        """Replay workers stop stepping once the pool-wide env-step count reaches ``max_env_steps``.

        They never wait for the learner otherwise, so without a limit a small step budget overshoots
        by whatever they collect while the learner compiles. Each worker checks before every env step,
        so the count ends below ``max_env_steps + num_workers * envs_per_worker``. None: no limit.
        Serial workers step only when asked and ignore it.
        """
        if max_env_steps is not None and self.buffer_kind != "replay":
            raise ValueError("a step limit is for replay buffers")
        self._ctl["flags"][STEP_LIMIT] = -1 if max_env_steps is None else max(int(max_env_steps), 0)

    def step_limit_reached(self) -> bool:
        """True once the env-step limit is set and reached (process workers then make no more steps)."""
        limit = int(self._ctl["flags"][STEP_LIMIT])
        return 0 <= limit <= self.env_steps()

    def publish(self, weights: Any, version: int) -> None:
        """Publishes a numpy weight pytree (same structure as the template) as ``version``."""
        self.weights.publish(weights, version)
        self.version = int(version)

    # ---- trajectory mode ----------------------------------------------------------------------
    def _need(self, kind: str) -> None:
        if self.buffer_kind != kind:
            raise RuntimeError(f"{self.algo_module} uses a {self.buffer_kind} buffer; this call needs {kind}")
        if not self._started:
            raise RuntimeError("call pool.start() first")
        if self._res.closed:
            raise RuntimeError("the pool is closed")

    def _pump_serial(self, worker: int) -> None:
        if not self._serial_workers[worker].run_chunk(block=False):
            raise RuntimeError(
                f"serial worker {worker} cannot collect: "
                + (f"lockstep needs weights newer than version {self._serial_workers[worker].chunk_version}; "
                   "publish before collect" if self.sync == "lockstep" or self.version < 0
                   else "no free slot")
            )

    def collect(self, n_slots: int | None = None, timeout: float = 600.0,
                out: dict[str, np.ndarray] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Takes ``n_slots`` full slots (default one per worker), copies them out, releases them.

        Returns ``({field: [T, n_slots * M, ...]}, info)``; slots are ordered by worker, then by
        publication. In lockstep mode ``n_slots`` must be ``num_workers`` (one slot per worker per
        weight version). ``out`` may pass preallocated arrays of those shapes to reuse.
        """
        self._need("trajectory")
        n = self.num_workers if n_slots is None else int(n_slots)
        if n <= 0:
            raise ValueError("n_slots must be positive")
        if self.sync == "lockstep" and n != self.num_workers:
            raise ValueError(f"lockstep collect takes one slot per worker: n_slots={self.num_workers}, got {n}")
        buf: TrajectoryBuffer = self.buffer  # type: ignore[assignment]
        if n > self.num_workers * buf.slots_per_worker:
            raise ValueError(f"collect(n_slots={n}) needs more slots than the {self.num_workers} x "
                             f"{buf.slots_per_worker} that exist (slots are released after the copy)")
        t0 = time.monotonic()
        taken: list[tuple[int, int, int]] = []  # (worker, sequence, slot)
        try:
            self._take_slots(buf, n, t0, timeout, taken)
        except BaseException:
            for w, _, slot in taken:  # nothing was copied: hand the slots back
                self._release(buf, w, slot)
            raise
        wait_s = time.monotonic() - t0
        taken.sort()
        batch = out if out is not None else buf.empty_batch(n)
        m = self.envs_per_worker
        for j, (w, _, slot) in enumerate(taken):
            buf.copy_slot(w, slot, batch, col=j * m)
        for w, _, slot in taken:
            self._release(buf, w, slot)
        versions = batch["policy_version"]
        info = {
            "workers": [w for w, _, _ in taken],
            "policy_version_min": int(versions.min()),
            "policy_version_max": int(versions.max()),
            "wait_s": wait_s,
            "copy_s": time.monotonic() - t0 - wait_s,
            "n_slots": n,
        }
        return batch, info

    def _release(self, buf: TrajectoryBuffer, w: int, slot: int) -> None:
        self._held[w].discard(slot)
        buf.release(w, slot)

    def _took(self, buf: TrajectoryBuffer, w: int, got: tuple[int, int], taken: list) -> None:
        taken.append((w, got[1], got[0]))
        self._held[w].add(got[0])
        if self.sync == "lockstep":
            self._last_taken_version[w] = int(buf.slot(w, got[0])["policy_version"][0, 0])

    def _take_slots(self, buf: TrajectoryBuffer, n: int, t0: float, timeout: float, taken: list) -> None:
        """Takes ``n`` verified full slots into ``taken`` (respawning dead workers while it waits)."""
        if self.sync == "lockstep":
            for w in range(self.num_workers):
                if self.serial:
                    self._pump_serial(w)
                got = wait_for(lambda w=w: buf.take(w), timeout=self._remaining(t0, timeout),
                               check=self._check_workers, poll=self.poll, what=f"slot from worker {w}")
                self._took(buf, w, got, taken)
        else:
            per_worker = np.zeros(self.num_workers, np.int64)
            rr = 0
            while len(taken) < n:
                if self.serial:
                    w = int(np.argmin(per_worker))
                    if buf.ready(w) == 0:
                        self._pump_serial(w)
                    got = buf.take(w)
                else:
                    got = None
                    for k in range(self.num_workers):
                        w = (rr + k) % self.num_workers
                        got = buf.take(w)
                        if got is not None:
                            break
                    rr = (rr + 1) % self.num_workers
                    if got is None:
                        try:
                            self._maybe_check_workers()
                            remaining = self._remaining(t0, timeout)
                            wait_for(lambda: True if any(buf.ready(i) for i in range(self.num_workers)) else None,
                                     timeout=min(remaining, self.poll), what="full slot")
                        except RingTimeout:
                            pass
                        continue
                self._took(buf, w, got, taken)
                per_worker[w] += 1

    def _remaining(self, t0: float, timeout: float) -> float:
        left = timeout - (time.monotonic() - t0)
        if left <= 0:
            raise TimeoutError(f"collect timed out after {timeout:.1f} s; worker status: {self._status_line()}")
        return left

    def _status_line(self) -> str:
        words = self._ctl["worker"]
        return ", ".join(f"w{i} (pid {words[i, PID]}): steps={words[i, STEPS]} chunks={words[i, CHUNKS]} "
                         f"version={words[i, VERSION]} restarts={self._restarts[i]}" for i in range(self.num_workers))

    # ---- replay mode --------------------------------------------------------------------------
    def pump(self, steps: int = 1) -> int:
        """Serial replay mode: runs ``steps`` env steps in every worker (no-op with processes)."""
        if not self.serial:
            return 0
        self._need("replay")
        return sum(w.run_steps(steps) for w in self._serial_workers)

    def replay_size(self) -> int:
        self._need("replay")
        return self.buffer.size()  # type: ignore[union-attr]

    def sample(self, batch_size: int, rng: np.random.Generator, serial_steps: int = 1) -> dict[str, np.ndarray]:
        """``{field: [B, ...]}`` sampled uniformly from every worker's replay region.

        In serial mode first runs ``serial_steps`` env steps per worker.
        """
        self.before_sample(serial_steps)
        return self.buffer.sample(batch_size, rng)  # type: ignore[union-attr]

    def before_sample(self, serial_steps: int = 1) -> None:
        """What precedes reading the replay rings: serial mode runs ``serial_steps`` env steps per worker,
        process mode notices dead workers."""
        self._need("replay")
        if self.serial:
            self.pump(serial_steps)
        else:
            self._maybe_check_workers()

    def wait_replay(self, min_size: int, timeout: float = 600.0) -> int:
        """Blocks until the replay buffer holds ``min_size`` transitions (serial: pumps)."""
        self._need("replay")
        most = self.num_workers * self.buffer.capacity  # type: ignore[union-attr]
        if min_size > most:
            raise ValueError(f"wait_replay({min_size}): the replay capacity is {most} transitions in all")
        t0 = time.monotonic()
        while self.replay_size() < min_size:
            if self.serial:
                if self.pump(1) == 0:
                    raise RuntimeError("serial workers cannot step: publish weights first")
            else:
                self._remaining(t0, timeout)
                self._maybe_check_workers()
                time.sleep(min(self.poll, 0.01))
        return self.replay_size()

    # ---- monitoring ---------------------------------------------------------------------------
    def env_steps(self) -> int:
        return int(self._ctl["worker"][:, STEPS].sum())

    def stats(self) -> dict[str, Any]:
        """Env steps and rates, recent episodes, per-term reward means (since the previous call; see
        ``unilab_jax/runtime/pool_stats.py``)."""
        return self._stats.read(self.version, sum(self._restarts), self.buffer)
