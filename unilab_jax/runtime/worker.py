"""Rollout worker: MuJoCo task + numpy policy inference, writing transitions into shared memory.

A :class:`Worker` runs in a spawned process (:func:`worker_main`) or, in serial mode, inside the
learner process; both run the same code. Per *chunk* (``T`` control steps) it

1. gets weights through the weight channel: in ``"lockstep"`` mode it waits until the published
   version is newer than the one that produced its previous chunk; in ``"async"`` mode it never
   waits (after the very first publish) and picks up newer weights before every step (a worker process
   whose weights are large, >= ``PREFETCH_MIN_BYTES``, copies them in a background thread meanwhile:
   :class:`~unilab_jax.runtime.weights.WeightPrefetcher`);
2. in trajectory mode takes a free slot (waiting for one if the learner holds them all);
3. steps its ``M`` envs ``T`` times: noise from its own ``np.random.Generator``, ``act`` (numpy),
   ``task.step``, and writes every field of the transition straight into the slot (or the replay
   rows at its cursor), stamping ``policy_version`` and tracking per-env episode return / length;
4. publishes the slot (trajectory) or commits each step's rows (replay).

Only numpy, mujoco, the task, the algorithm module and its contract (``unilab_jax.algos.contract``, pure
standard library) are imported here; never jax.
Counters for monitoring (env steps, finished episodes, reward-term sums, status, errors) live in a
small shared control segment that the learner reads in :meth:`WorkerPool.stats`.

Faults the worker guards against itself:

* **Non-finite values.** A row (one env's transition) with a NaN/Inf in any float field (obs,
  critic obs, action, reward, reward terms, successors, the policy's extras) is zeroed and marked
  truncated before it is published, so nothing non-finite reaches the learner and no return is
  bootstrapped through it; the env is reset when the task offers ``reset_envs(idx) -> (obs,
  critic_obs)`` (rows of ``idx``), and the rows are counted (``NONFINITE``). Tasks already truncate
  their own MuJoCo divergences; this catches the rest (a policy with NaN weights, a buggy reward).
* **Liveness.** :meth:`Worker._check` (run every step and every ``poll`` while waiting) bumps the
  ``HEARTBEAT`` word, which the pool watches to find a stopped or hung worker.
* **Interrupted steps.** A task whose step could not complete (a lost robot: ``tasks.base.StepInterrupted``)
  writes nothing for that step: the replay rows are not committed (a trajectory step is taken again in
  the same slot row, the previous row marked truncated, so no return is bootstrapped across the gap);
  the envs continue from the observations the task gives, and the steps are counted (``INTERRUPTED``).
  The task keeps the worker alive while it waits through ``task.keepalive`` (the worker's ``_check``,
  which also raises ``WAITING`` until the task's step returns: the pool counts waiting workers).
* **Step budget.** Replay workers never wait for the learner; when the pool sets an env-step limit
  (``flags[STEP_LIMIT]``) they stop stepping once the pool-wide count reaches it (still heartbeating
  and answering the stop flag).
"""

from __future__ import annotations

import dataclasses
import importlib
import os
import signal
import sys
import time
import traceback
from typing import Any

import numpy as np

from unilab_jax.algos import contract
from unilab_jax.runtime.buffers import ReplayBuffer, TrajectoryBuffer
from unilab_jax.runtime.ring import fence
from unilab_jax.runtime.shm import SharedArrays, ShmHandle
from unilab_jax.runtime.weights import WeightPrefetcher, WeightReader

__all__ = ["Worker", "WorkerArgs", "control_layout", "worker_main", "Stopped"]

# Async worker processes read weights of at least this size in a background thread: a copy plus checksum
# runs at ~6-10 GB/s, so from here on a read between two steps would take milliseconds of the control loop
# (256 MB: ~40 ms on the 2-core dev VM, a 10 Hz robot's period is 100 ms).
PREFETCH_MIN_BYTES = 8 << 20

# Per-worker int64 words of the control segment ("worker" [W, 16]). RESUME_VERSION is written by the
# pool before it respawns a lockstep worker: the version of the last chunk that worker published.
(STEPS, STATUS, PID, EPISODES, VERSION, CHUNKS, HEARTBEAT, W_READS, W_RETRIES, JAX, TERM_ROWS, NONFINITE,
 RESUME_VERSION, INTERRUPTED, WAITING) = range(15)
# Pool-wide words ("flags" [16]): the stop flag and the env-step limit (-1: none).
STOP_FLAG, STEP_LIMIT = 0, 1
# Status values.
NEW, READY, STOPPED, FAILED = 0, 1, 2, 3
ERROR_BYTES = 4096
EPISODE_WINDOW = 64


# Where a worker's wall time goes (cumulative seconds in ctl["timing"]): the profile behind every
# throughput number (policy inference, MuJoCo + task math, writing transitions, waiting for weights
# or a free slot).
TIMING = ("act", "task", "write", "wait")


def control_layout(num_workers: int, n_terms: int, episode_window: int = EPISODE_WINDOW) -> dict:
    return {
        "flags": ((16,), np.int64),  # [0]: stop
        "worker": ((num_workers, 16), np.int64),
        "ep_return": ((num_workers, episode_window), np.float32),
        "ep_length": ((num_workers, episode_window), np.int32),
        "ep_terminated": ((num_workers, episode_window), np.uint8),
        "term_sum": ((num_workers, max(n_terms, 1)), np.float64),  # reward terms, then episode metrics
        "timing": ((num_workers, len(TIMING)), np.float64),  # seconds spent per phase, see TIMING
        "error": ((num_workers, ERROR_BYTES), np.uint8),
    }


def init_control(ctl: SharedArrays) -> None:
    ctl["flags"][:] = 0
    ctl["flags"][STEP_LIMIT] = -1
    ctl["worker"][:] = 0
    ctl["worker"][:, VERSION] = -1
    ctl["worker"][:, RESUME_VERSION] = -1
    ctl["term_sum"][:] = 0.0
    ctl["timing"][:] = 0.0
    ctl["error"][:] = 0


class Stopped(Exception):
    """The pool asked the worker to stop (or the learner process died)."""


@dataclasses.dataclass(frozen=True)
class WorkerArgs:
    """Everything a worker needs (picklable, sent to the spawned process)."""

    worker_id: int
    task_name: str
    task_overrides: tuple[tuple[str, Any], ...]
    envs_per_worker: int
    seed: int  # the pool's seed; the worker uses seed * 1000 + worker_id
    algo_module: str
    sync: str  # "lockstep" | "async"
    buffer_kind: str  # "trajectory" | "replay"
    horizon: int
    buffer_handle: Any
    weights_handle: Any
    control_handle: ShmHandle
    parent_pid: int
    wait_timeout: float | None = None  # None: wait for weights / slots until stopped
    restarts: int = 0  # how often the pool has respawned this worker (a new seed each time)

    @property
    def worker_seed(self) -> int:
        """A respawned worker must not replay the episodes (and noise) its predecessor already wrote."""
        return self.seed * 1000 + self.worker_id + 1000003 * self.restarts


class Worker:
    """One worker's envs, policy and shared-memory writers (process or serial mode)."""

    def __init__(self, args: WorkerArgs):
        import tasks  # numpy + mujoco + the shim

        self.args = args
        self.id = args.worker_id
        self.algo = importlib.import_module(args.algo_module)
        self.ctl = SharedArrays.attach(args.control_handle)
        self._words = self.ctl["worker"][self.id]
        self._timing = self.ctl["timing"][self.id]
        self._words[PID] = os.getpid()
        self._flags = self.ctl["flags"]
        if args.buffer_kind == "trajectory":
            self.traj: TrajectoryBuffer | None = TrajectoryBuffer.attach(args.buffer_handle)
            self.replay: ReplayBuffer | None = None
        else:
            self.traj, self.replay = None, ReplayBuffer.attach(args.buffer_handle)
        fields = (self.traj or self.replay).fields
        # Float fields checked for NaN/Inf per row (episode_return is derived from the masked reward).
        self._finite_fields = [n for n, (shape, dt) in fields.items()
                               if dt.kind == "f" and n != "episode_return" and int(np.prod(shape)) > 0]
        self._nonfinite_logged = False
        self.weights = WeightReader(args.weights_handle)
        self._prefetch: WeightPrefetcher | None = None
        self._may_prefetch = False  # process mode sets it (run); serial workers read in the learner's turn
        self.task = tasks.make(args.task_name, args.envs_per_worker, args.worker_seed, dict(args.task_overrides))
        self.task.keepalive = self._keepalive
        self._interrupted = tasks.base.StepInterrupted
        self.spec = self.task.spec
        self._task_fields = [name for name, _, _ in getattr(self.spec, "transition_fields", ())]
        self._images = bool(getattr(self.spec, "image_shape", ()))  # the policy acts on task.images() too
        self._episode_metrics = tuple(getattr(self.spec, "episode_metrics", ()))
        self._reset_envs = getattr(self.task, "reset_envs", None)
        self.m = args.envs_per_worker
        self.rng = np.random.default_rng(np.random.SeedSequence([args.worker_seed, 0x5EED]))
        hooks = contract.hooks(self.algo)  # the declaration's optional hooks, defaults filled in
        # Exploration noise held for NOISE_HOLD_STEPS control steps per env (1: a fresh draw every step).
        # Redrawn early when an env's episode ends.
        self.noise_hold = hooks.noise_hold_steps
        # Standard normals per env step: the action dimension, or the algorithm's ``noise_dim(action_dim)``.
        self.noise_dim = int(hooks.noise_dim(self.spec.action_dim))
        self._noise = np.zeros((self.m, self.noise_dim), np.float32)
        self._noise_left = np.zeros(self.m, np.int64)  # steps each env's current draw is still held
        self.obs, self.critic_obs = self.task.reset()
        self.ep_return = np.zeros(self.m, np.float32)
        self.ep_length = np.zeros(self.m, np.int32)
        self.params: Any = None
        self.version = -1
        self.chunk_version = int(self._words[RESUME_VERSION])  # version that produced the previous chunk
        self._extras_checked = False
        self._last_parent_check = time.monotonic()
        self._words[JAX] = int("jax" in sys.modules)
        self._words[STATUS] = READY

    # ---- control ------------------------------------------------------------------------------
    def _check(self) -> None:
        """Raises :class:`Stopped` when the pool stops us or the learner process is gone; heartbeats."""
        if self._flags[STOP_FLAG]:
            raise Stopped()
        self._words[HEARTBEAT] += 1
        now = time.monotonic()
        if now - self._last_parent_check > 1.0:
            self._last_parent_check = now
            if self.args.parent_pid != os.getpid() and os.getppid() != self.args.parent_pid:
                raise Stopped()

    def _keepalive(self) -> None:
        """What a task calls while it waits inside a step (e.g. for a lost robot)."""
        self._words[WAITING] = 1
        self._check()

    def _wait_for_budget(self) -> None:
        """Blocks while the pool-wide env-step count is at the pool's limit (replay workers only)."""
        t0 = time.perf_counter()
        words = self.ctl["worker"]
        while 0 <= int(self._flags[STEP_LIMIT]) <= int(words[:, STEPS].sum()):
            self._check()
            time.sleep(0.01)
        self._timing[3] += time.perf_counter() - t0

    def _get_weights(self, block: bool) -> bool:
        """Loads the weights for a new chunk; False if (non-blocking) they are not there yet."""
        need = self.chunk_version + 1 if self.args.sync == "lockstep" else 0
        if self.version >= need and self.args.sync == "async":
            got = self._poll_async()
        elif block:
            got = self.weights.read(min_version=need, timeout=self.args.wait_timeout, check=self._check)
        else:
            got = self.weights.poll() if self.weights.latest_version() >= need else None
            if got is None and self.version < need:
                return False
        if got is not None:
            self._set_weights(*got)
        return self.version >= need

    def _poll_async(self) -> tuple[Any, int] | None:
        """Async mode: newer weights if a copy is ready (from the prefetch thread once it runs)."""
        return self._prefetch.take() if self._prefetch is not None else self.weights.poll()

    def _set_weights(self, tree: Any, version: int) -> None:
        self.params, self.version = tree, version
        self._words[W_READS] += 1
        self._words[W_RETRIES] = self.weights.retries
        self._words[VERSION] = version
        if (self._may_prefetch and self._prefetch is None and self.args.sync == "async"
                and self.weights.handle.nbytes >= PREFETCH_MIN_BYTES):
            self._prefetch = WeightPrefetcher(self.weights)

    # ---- one env step -------------------------------------------------------------------------
    def _step(self, out: dict[str, np.ndarray]) -> bool:
        """Acts, steps the task and writes one transition per env into ``out`` ({field: [M, ...]}); False
        (nothing valid written) when the task interrupted the step."""
        self._check()
        if self.args.sync == "async":
            got = self._poll_async()
            if got is not None:
                self._set_weights(*got)
        t0 = time.perf_counter()
        noise = self._exploration_noise()
        if self._images:
            action, extras = self.algo.act(self.params, self.obs, noise, False, image=self.task.images())
        else:
            action, extras = self.algo.act(self.params, self.obs, noise, False)
        action = np.asarray(action, dtype=np.float32)
        if not self._extras_checked:
            self._check_extras(action, extras)
        t1 = time.perf_counter()
        out["obs"][...] = self.obs
        out["critic_obs"][...] = self.critic_obs
        out["action"][...] = action
        for name, value in extras.items():
            out[name][...] = np.asarray(value)
        t2 = time.perf_counter()
        try:
            res = self.task.step(action)
        except self._interrupted as e:
            self._words[WAITING] = 0
            sys.stderr.write(f"[unilab worker {self.id}] step interrupted, no transition written: {e}\n")
            sys.stderr.flush()
            self.obs, self.critic_obs = e.obs, e.critic_obs
            self.ep_return[:] = 0.0
            self.ep_length[:] = 0
            self._noise_left[:] = 0
            self._words[INTERRUPTED] += 1
            self._timing[1] += time.perf_counter() - t2
            return False
        t3 = time.perf_counter()
        if self._words[WAITING]:
            self._words[WAITING] = 0
        task_extras = res.extras or {}
        if "action" in task_extras:  # the task executed another action (an operator's) than the policy's
            out["action"][...] = task_extras["action"]
        for name in self._task_fields:
            out[name][...] = task_extras[name]
        out["reward"][...] = res.reward
        out["terminated"][...] = res.terminated
        out["truncated"][...] = res.truncated
        out["next_obs"][...] = res.next_obs
        out["next_critic_obs"][...] = res.next_critic_obs
        terms = out["reward_terms"]
        for i, name in enumerate(self.spec.reward_terms):
            terms[:, i] = res.reward_terms[name]
        bad = self._mask_nonfinite(out)
        ended = np.logical_or(out["terminated"], out["truncated"])
        if self.noise_hold > 1:
            self._noise_left[ended] = 0  # new episode: new draw
        self.ep_return += out["reward"]
        self.ep_length += 1
        out["episode_return"][...] = self.ep_return
        out["episode_length"][...] = self.ep_length
        out["policy_version"][...] = self.version
        self.obs, self.critic_obs = res.obs, res.critic_obs
        if bad is not None:
            self._restart_envs(bad)
        # Monitoring counters (single-writer words; approximate reads are fine).
        ctl, w = self.ctl, self.id
        if self.spec.reward_terms:
            ctl["term_sum"][w, : len(self.spec.reward_terms)] += terms.sum(axis=0, dtype=np.float64)
        self._words[TERM_ROWS] += self.m
        done = np.flatnonzero(ended)
        if done.size:
            window = ctl["ep_return"].shape[1]
            n0 = int(self._words[EPISODES])
            pos = (n0 + np.arange(done.size)) % window
            ctl["ep_return"][w, pos[-window:]] = self.ep_return[done][-window:]
            ctl["ep_length"][w, pos[-window:]] = self.ep_length[done][-window:]
            ctl["ep_terminated"][w, pos[-window:]] = out["terminated"][done][-window:]
            self._words[EPISODES] = n0 + done.size
            for j, name in enumerate(self._episode_metrics):  # after the reward terms' columns
                ctl["term_sum"][w, len(self.spec.reward_terms) + j] += float(np.sum(task_extras[name][done]))
            self.ep_return[done] = 0.0
            self.ep_length[done] = 0
        self._words[STEPS] += self.m
        timing = self._timing
        timing[0] += t1 - t0
        timing[1] += t3 - t2
        timing[2] += (t2 - t1) + (time.perf_counter() - t3)
        return True

    def _mask_nonfinite(self, out: dict[str, np.ndarray]) -> np.ndarray | None:
        """Zeroes and truncates the rows of ``out`` holding a NaN/Inf; returns their env indices (or None).

        One vectorised ``isfinite`` per field; the masking itself runs only when something is bad.
        """
        bad = None
        names = []
        for name in self._finite_fields:
            ok = np.isfinite(out[name].reshape(self.m, -1)).all(axis=1)
            if not ok.all():
                bad = ~ok if bad is None else bad | ~ok
                names.append(name)
        if bad is None:
            return None
        for name in self._finite_fields:
            out[name][bad] = 0
        out["terminated"][bad] = False
        out["truncated"][bad] = True
        if not self._nonfinite_logged:
            self._nonfinite_logged = True
            sys.stderr.write(f"[unilab worker {self.id}] non-finite values in {names}: rows zeroed, episodes "
                             "truncated (counted in the pool's nonfinite_rows; reported once)\n")
            sys.stderr.flush()
        return np.flatnonzero(bad)

    def _restart_envs(self, idx: np.ndarray) -> None:
        """Counts masked rows; resets their envs when the task can reset a subset of them."""
        self._words[NONFINITE] += idx.size
        if self._reset_envs is None:
            return
        obs, critic_obs = self._reset_envs(idx)
        self.obs, self.critic_obs = np.array(self.obs, np.float32), np.array(self.critic_obs, np.float32)
        self.obs[idx] = obs
        self.critic_obs[idx] = critic_obs

    def _exploration_noise(self) -> np.ndarray:
        """Standard normal ``[M, noise_dim]``: a fresh draw every step, or each env's draw held for
        ``noise_hold`` steps (vectorised: only the envs whose hold ran out draw again)."""
        if self.noise_hold <= 1:
            return self.rng.standard_normal((self.m, self.noise_dim), dtype=np.float32)
        redraw = np.flatnonzero(self._noise_left <= 0)
        if redraw.size:
            self._noise[redraw] = self.rng.standard_normal((redraw.size, self.noise_dim), dtype=np.float32)
            self._noise_left[redraw] = self.noise_hold
        self._noise_left -= 1
        return self._noise.copy()

    def _check_extras(self, action: np.ndarray, extras: dict) -> None:
        want = set(self.algo.extras(self.spec.action_dim))
        if set(extras) != want:
            raise ValueError(f"{self.args.algo_module}.act returned extras {sorted(extras)}, declared {sorted(want)}")
        if action.shape != (self.m, self.spec.action_dim):
            raise ValueError(f"{self.args.algo_module}.act returned actions of shape {action.shape}, "
                             f"expected {(self.m, self.spec.action_dim)}")
        self._extras_checked = True

    # ---- chunks -------------------------------------------------------------------------------
    def run_chunk(self, block: bool = True) -> bool:
        """Collects one chunk of ``T`` steps (a trajectory slot or T replay steps).

        With ``block=False`` (serial mode) returns False instead of waiting when the weights it
        needs are not published yet or no slot is free.
        """
        t_wait = time.perf_counter()
        if not self._get_weights(block):
            return False
        t_len = self.args.horizon
        if self.traj is not None:
            if block:
                slot = self.traj.acquire(self.id, timeout=self.args.wait_timeout, check=self._check)
            else:
                slot = self.traj.try_acquire(self.id)
                if slot is None:
                    return False
            self._timing[3] += time.perf_counter() - t_wait
            views = self.traj.slot(self.id, slot)
            start_version = self.version
            for t in range(t_len):
                while not self._step({k: v[t] for k, v in views.items()}):
                    if t > 0:  # the previous row's successor is real, but the episode is gone
                        views["truncated"][t - 1] |= ~views["terminated"][t - 1]
            self.traj.publish(self.id, slot)
        else:
            start_version = self.version
            for _ in range(t_len):
                if block:
                    self._wait_for_budget()
                _, rows = self.replay.rows(self.id)
                if self._step(rows):
                    self.replay.commit(self.id)
        self.chunk_version = start_version if self.args.sync == "lockstep" else self.version
        self._words[CHUNKS] += 1
        return True

    def run_steps(self, n: int) -> int:
        """Replay mode, serial: up to ``n`` single env steps (no chunk wait); returns steps done."""
        if self.replay is None:
            raise RuntimeError("run_steps is for replay buffers")
        done = 0
        for _ in range(n):
            if self.params is None or self.args.sync == "async":
                got = self.weights.poll()
                if got is not None:
                    self._set_weights(*got)
            if self.params is None:
                break
            _, rows = self.replay.rows(self.id)
            if self._step(rows):
                self.replay.commit(self.id)
                done += 1
        return done

    def run(self) -> None:
        """Process mode: chunks until stopped."""
        self._may_prefetch = True
        while True:
            self.run_chunk(block=True)

    def close(self) -> None:
        if self._prefetch is not None:
            self._prefetch.close()
        for obj in (self.traj, self.replay, self.weights):
            if obj is not None:
                obj.close()
        try:
            self.task.close()
        finally:
            self.params = None
            self.ctl.close()


def _report_error(ctl: SharedArrays | None, worker_id: int, text: str) -> None:
    if ctl is None:
        return
    data = text.encode("utf-8", "replace")[-(ERROR_BYTES - 1):]
    err = ctl["error"][worker_id]
    err[:] = 0
    err[: len(data)] = np.frombuffer(data, np.uint8)
    fence()
    ctl["worker"][worker_id, STATUS] = FAILED


def read_error(ctl: SharedArrays, worker_id: int) -> str:
    raw = bytes(ctl["error"][worker_id])
    return raw.split(b"\0", 1)[0].decode("utf-8", "replace")


def worker_main(args: WorkerArgs) -> None:
    """Entry point of a spawned worker process."""
    # Ctrl-C and `timeout`/`kill -TERM -<pgid>` reach the whole process group: the learner handles
    # them (final checkpoint, then it stops us via the shared flag; close() escalates to SIGKILL after
    # its grace period), and a worker whose learner is gone exits on its own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    ctl = None
    worker = None
    try:
        ctl = SharedArrays.attach(args.control_handle)
        worker = Worker(args)
        worker.run()
    except Stopped:
        if ctl is not None:
            ctl["worker"][args.worker_id, STATUS] = STOPPED
    except BaseException:
        text = traceback.format_exc()
        sys.stderr.write(f"[unilab worker {args.worker_id}] crashed:\n{text}")
        sys.stderr.flush()
        _report_error(ctl, args.worker_id, text)
        raise SystemExit(1) from None
    finally:
        if worker is not None:
            try:
                worker.close()
            except Exception:
                pass
        if ctl is not None:
            ctl.close()
