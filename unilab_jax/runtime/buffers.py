"""Shared-memory transition buffers: trajectory slots (on-policy) and per-worker replay rings.

Both are built from a per-transition layout (:func:`transition_layout`: the task's fields from
``TaskSpec`` plus the algorithm's extras), poison-filled at creation (NaN floats, -1 / max ints,
True bools; ``policy_version == -1`` marks an unwritten transition), and shared between one
learner and ``num_workers`` workers. The creator (learner) owns and unlinks the segments; workers
attach through the picklable ``handle``.

:class:`TrajectoryBuffer`
    Per worker ``K`` slots, each holding every field as ``[T, M, ...]`` (horizon ``T``, the
    worker's ``M`` envs), contiguous in memory (one slot = one byte range). Slot indices circulate
    through two lock-free SPSC rings per worker (:mod:`unilab_jax.runtime.ring`): *free*
    (learner -> worker) and *full* (worker -> learner). A worker publishes a slot with a checksum
    of its bytes mixed with the full ring's sequence number; the learner verifies it before
    reading, so it never reads a half-visible slot.

:class:`ReplayBuffer`
    Per worker a ring region of capacity ``C`` transitions (rounded up to a multiple of ``M``, at
    least ``2 M``), written by the worker ``M`` rows (one env step) at a time at its own cursor; the
    cursor is published as a transition counter (one aligned int64 store) after the rows. All
    regions live in one segment (every field ``[num_workers, C, ...]``), so the learner gathers a
    batch with one ``np.take`` per field, straight into the output in the order drawn. The learner
    samples uniformly over the committed rows of all regions that no writer is about to overwrite,
    and validates the copy by the counters (a seqlock on the cursor, see :meth:`ReplayBuffer.sample`):
    a row the writer may have reached during the copy is redrawn. The writer also stores per-row
    checksums, which the ring spiller of :mod:`unilab_jax.runtime.replay_store` verifies (a ring created with
    ``row_sums=False``, as runs without a replay store make it, skips them).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from unilab_jax.runtime.ring import RingTimeout, SpscRing, checksum, fence, ring_words, wait_for
from unilab_jax.runtime.shm import SharedArrays, ShmHandle

__all__ = [
    "BASE_FIELDS",
    "ReplayBuffer",
    "SlotCorruptError",
    "TrajectoryBuffer",
    "row_checksums",
    "transition_layout",
]

# The task's per-transition fields, in memory order (extras follow).
BASE_FIELDS = (
    "obs", "critic_obs", "action", "reward", "terminated", "truncated", "next_obs", "next_critic_obs",
    "reward_terms", "episode_return", "episode_length", "policy_version",
)

FieldLayout = dict[str, tuple[tuple[int, ...], np.dtype]]


class SlotCorruptError(RuntimeError):
    """Slot data never matched its checksum (a writer bug or memory corruption)."""


def transition_layout(spec: Any, extras: Mapping[str, tuple[tuple[int, ...], Any]] | None = None) -> FieldLayout:
    """Per-transition ``{field: (shape, dtype)}`` from a ``TaskSpec`` (with its ``transition_fields``) and an
    algorithm's extras."""
    f32 = np.dtype(np.float32)
    layout: FieldLayout = {
        "obs": ((spec.obs_dim,), f32),
        "critic_obs": ((spec.critic_obs_dim,), f32),
        "action": ((spec.action_dim,), f32),
        "reward": ((), f32),
        "terminated": ((), np.dtype(bool)),
        "truncated": ((), np.dtype(bool)),
        "next_obs": ((spec.obs_dim,), f32),
        "next_critic_obs": ((spec.critic_obs_dim,), f32),
        "reward_terms": ((len(spec.reward_terms),), f32),
        "episode_return": ((), f32),
        "episode_length": ((), np.dtype(np.int32)),
        "policy_version": ((), np.dtype(np.int64)),
    }
    task_fields = {name: (shape, dtype) for name, shape, dtype in getattr(spec, "transition_fields", ())}
    for name, (shape, dtype) in {**task_fields, **(extras or {})}.items():
        if name in layout:
            raise ValueError(f"extra field {name!r} (the task's or the algorithm's) collides with a transition field")
        layout[name] = (tuple(int(s) for s in shape), np.dtype(dtype))
    return layout


_WORDS = {1: np.uint8, 2: np.uint16, 4: np.uint32, 8: np.uint64}
_SEED, _MUL1, _MUL2 = np.uint64(0x9E3779B97F4A7C15), np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)
_SHIFT1, _SHIFT2 = np.uint64(29), np.uint64(31)


def _as_words(a: np.ndarray) -> np.ndarray:
    """Reinterprets ``a`` as unsigned ints of the same itemsize (works on strided views)."""
    return a.view(_WORDS[a.dtype.itemsize])


def row_checksums(rows: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """Per-row uint64 checksum over every field of ``rows`` (each [n, ...]); sorted field order.

    Written identically by the replay writer (on its rows in shared memory) and the sampler (on
    its gathered copy): per field a wrapped sum and an xor of the row's words, folded with odd
    multipliers, then a splitmix64 finalizer. A worker checksums its few rows on every env step, so
    the per-field numpy calls are kept few (one-word fields skip the reductions: their sum and xor
    are the word itself).
    """
    h = np.full(n, _SEED, dtype=np.uint64)
    with np.errstate(over="ignore"):
        for name in sorted(rows):
            a = rows[name]
            u = _as_words(a.reshape(n, math.prod(a.shape[1:])))
            if u.shape[1] == 1:
                s = x = u[:, 0].astype(np.uint64)
            elif u.shape[1]:
                s = u.sum(axis=1, dtype=np.uint64)
                x = np.bitwise_xor.reduce(u, axis=1).astype(np.uint64)
            else:
                s = x = np.zeros(n, np.uint64)
            h ^= s
            h *= _MUL1
            folded = h >> _SHIFT1
            h ^= x
            h ^= folded
            h *= _MUL2
        h ^= h >> _SHIFT2
    return h


def _pad8(n: int) -> int:
    return -(-n // 8) * 8


@dataclasses.dataclass(frozen=True)
class _BufferHandle:
    """What every buffer's handle (the picklable description a worker attaches with) starts with."""

    fields: tuple[tuple[str, tuple[int, ...], str], ...]
    num_workers: int
    envs_per_worker: int


# ---------------------------------------------------------------------------------------------
# Trajectory slots
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class TrajectoryBufferHandle(_BufferHandle):
    horizon: int
    slots_per_worker: int
    data: tuple[ShmHandle, ...]
    control: ShmHandle


class TrajectoryBuffer:
    """K slots of ``[T, M, ...]`` per worker, with free/full slot rings (see module docstring).

    Worker side: :meth:`acquire` / :meth:`try_acquire` a free slot, write :meth:`slot` views,
    :meth:`publish`. Learner side: :meth:`take` (verifies the checksum), :meth:`copy_slot`,
    :meth:`release`.
    """

    def __init__(self, handle: TrajectoryBufferHandle, data: list[SharedArrays], control: SharedArrays):
        self.handle = handle
        self.fields: FieldLayout = {n: (tuple(s), np.dtype(d)) for n, s, d in handle.fields}
        self.num_workers = handle.num_workers
        self.envs_per_worker = handle.envs_per_worker
        self.horizon = handle.horizon
        self.slots_per_worker = handle.slots_per_worker
        self._data = data
        self._control = control
        self.free = [SpscRing(control["free"][w]) for w in range(self.num_workers)]
        self.full = [SpscRing(control["full"][w]) for w in range(self.num_workers)]
        self._sums = control["slot_sum"]
        names = list(self.fields)
        self._raw = [[d.byte_range(f"{k}/{names[0]}", f"{k}/{names[-1]}") for k in range(self.slots_per_worker)]
                     for d in data]

    @classmethod
    def create(cls, fields: FieldLayout, num_workers: int, envs_per_worker: int, horizon: int,
               slots_per_worker: int = 2) -> TrajectoryBuffer:
        if min(num_workers, envs_per_worker, horizon, slots_per_worker) <= 0:
            raise ValueError("num_workers, envs_per_worker, horizon and slots_per_worker must be positive")
        t, m, k = int(horizon), int(envs_per_worker), int(slots_per_worker)
        words = ring_words(k)
        made: list[SharedArrays] = []
        try:
            control = SharedArrays.create(
                {
                    "free": ((num_workers, words), np.int64),
                    "full": ((num_workers, words), np.int64),
                    "slot_sum": ((num_workers, _pad8(k)), np.int64),
                },
                tag="tc",
            )
            made.append(control)
            data = []
            for w in range(num_workers):
                layout = {f"{s}/{name}": ((t, m, *shape), dt) for s in range(k) for name, (shape, dt) in fields.items()}
                data.append(SharedArrays.create(layout, tag=f"t{w}"))
                made.append(data[-1])
        except BaseException:
            for seg in made:
                seg.close()
            raise
        handle = TrajectoryBufferHandle(
            tuple((n, tuple(s), np.dtype(d).str) for n, (s, d) in fields.items()),
            int(num_workers), m, t, k, tuple(d.handle for d in data), control.handle,
        )
        buf = cls(handle, data, control)
        for w in range(num_workers):
            buf.free[w].init()
            buf.full[w].init()
            for s in range(k):
                buf.free[w].push(s)
        return buf

    @classmethod
    def from_spec(cls, spec: Any, extras: Mapping[str, tuple[tuple[int, ...], Any]] | None, num_workers: int,
                  envs_per_worker: int, horizon: int, slots_per_worker: int = 2) -> TrajectoryBuffer:
        """Built from a ``TaskSpec`` and an algorithm's ``extras(action_dim)``."""
        return cls.create(transition_layout(spec, extras), num_workers, envs_per_worker, horizon, slots_per_worker)

    @classmethod
    def attach(cls, handle: TrajectoryBufferHandle) -> TrajectoryBuffer:
        control = SharedArrays.attach(handle.control)
        data = [SharedArrays.attach(h) for h in handle.data]
        return cls(handle, data, control)

    def close(self) -> None:
        self.free, self.full = [], []
        self._sums, self._raw = None, []
        for seg in self._data:
            seg.close()
        self._control.close()

    @property
    def segment_names(self) -> list[str]:
        return [self._control.name] + [d.name for d in self._data]

    # ---- shared -------------------------------------------------------------------------------
    def slot(self, worker: int, slot: int) -> dict[str, np.ndarray]:
        """``{field: [T, M, ...]}`` views of one slot in shared memory."""
        seg = self._data[worker]
        return {name: seg[f"{slot}/{name}"] for name in self.fields}

    def _slot_bytes(self, worker: int, slot: int) -> np.ndarray:
        return self._raw[worker][slot]

    # ---- worker side --------------------------------------------------------------------------
    def try_acquire(self, worker: int) -> int | None:
        got = self.free[worker].pop()
        return None if got is None else got[0]

    def acquire(self, worker: int, timeout: float | None = None, check=None) -> int:
        return self.free[worker].pop_wait(timeout=timeout, check=check)[0]

    def publish(self, worker: int, slot: int) -> int:
        """Checksums the slot, stores the sum, then publishes the index; returns its sequence."""
        ring = self.full[worker]
        seq = ring.next_sequence()
        self._sums[worker, slot] = checksum(self._slot_bytes(worker, slot), seq)
        got = ring.push(slot)  # fences before the publishing store
        if got is None:
            raise RuntimeError(f"full-slot ring of worker {worker} overflowed (slot {slot} published twice?)")
        return got

    # ---- learner side -------------------------------------------------------------------------
    def ready(self, worker: int) -> int:
        """Number of full slots worker ``worker`` has published and the learner not taken."""
        return len(self.full[worker])

    def take(self, worker: int, verify_timeout: float = 5.0) -> tuple[int, int] | None:
        """Takes the next full slot of ``worker`` (or None): returns (slot, sequence) after verifying.

        The checksum is recomputed until it matches (the writer's bytes may reach this core after the
        index); :class:`SlotCorruptError` after ``verify_timeout`` seconds.
        """
        got = self.full[worker].peek()
        if got is None:
            return None
        slot, seq = got
        raw = self._slot_bytes(worker, slot)

        def verified():
            ok = checksum(raw, seq) == int(self._sums[worker, slot])
            if not ok:
                fence()
            return True if ok else None

        try:
            wait_for(verified, timeout=verify_timeout, what="slot checksum")
        except RingTimeout:
            raise SlotCorruptError(
                f"slot {slot} of worker {worker} (sequence {seq}) never matched its checksum"
            ) from None
        self.full[worker].advance()
        return slot, seq

    def copy_slot(self, worker: int, slot: int, out: Mapping[str, np.ndarray], col: int = 0) -> None:
        """Copies the slot into ``out[field][:, col:col+M]`` (out arrays are [T, >= col+M, ...])."""
        m = self.envs_per_worker
        for name, src in self.slot(worker, slot).items():
            out[name][:, col : col + m] = src

    def release(self, worker: int, slot: int) -> None:
        """Hands a taken slot back to its worker (after every read of it)."""
        fence()
        if self.free[worker].push(slot) is None:
            raise RuntimeError(f"free-slot ring of worker {worker} overflowed (slot {slot} released twice?)")

    def reclaim(self, worker: int, held: Iterable[int] = ()) -> list[int]:
        """After worker ``worker``'s process died: makes its rings consistent for a new process.

        Completes a publish the worker left half done (its slot is whole: the checksum is written
        before the publishing store), then hands back to the free ring every slot that is in
        neither ring nor ``held`` by the learner: the one the worker was writing, whose partial
        data no reader can take (it was never published, and the next publish re-checksums it).
        Returns the reclaimed slots. Learner side, only while no process of that worker runs.
        """
        self.full[worker].recover_producer()
        present = set(self.free[worker].pending()) | set(self.full[worker].pending()) | set(held)
        lost = [s for s in range(self.slots_per_worker) if s not in present]
        for s in lost:
            self.release(worker, s)
        return lost

    def empty_batch(self, n_slots: int) -> dict[str, np.ndarray]:
        t, m = self.horizon, self.envs_per_worker
        return {name: np.empty((t, n_slots * m, *shape), dt) for name, (shape, dt) in self.fields.items()}


# ---------------------------------------------------------------------------------------------
# Replay rings
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class ReplayBufferHandle(_BufferHandle):
    capacity: int
    data: ShmHandle
    control: ShmHandle
    row_sums: bool = True  # commits checksum their rows (only the ring spiller reads them)


def _barrier() -> None:
    """A full memory barrier: two :func:`fence` calls (lock acquire, release, acquire, release).

    A lock's acquire has acquire semantics and its release release semantics, and a release followed
    by an acquire is ordered (x86: locked instructions; arm64: ``stlr``/``stlxr``/LSE ``*l`` stores
    before ``ldaxr``/``casa``/``*a`` loads, RCsc), so every access before the middle release is
    ordered before every access after the middle acquire. One :func:`fence` alone is acquire then
    release, which does not order an earlier store with a later load where the lock is a glibc
    semaphore (CPython <= 3.12 on arm64 Linux). Costs ~0.2 us.
    """
    fence()
    fence()


class ReplayBuffer:
    """Per-worker ring regions of ``capacity`` transitions; uniform sampling over all valid rows.

    Worker side: ``start, views = rows(worker)`` (``{field: [M, ...]}`` views at the cursor), write
    them, :meth:`commit`. Learner side: :meth:`sample`, :meth:`size`.

    ``gather_threads``: threads that share a batch's copy by rows (``np.take`` releases the GIL; the
    copy is bound by memory latency, so more requests in flight help). Default: the usable cores, at
    most 4. 2 threads vs 1 on a 2-core VM shared with another job, 65,536 Go1 rows: median -15%,
    best call -45% (``bench/replay_sample.py``). Batches under ``2 * MIN_ROWS_PER_THREAD`` rows use
    the calling thread alone.
    """

    MIN_ROWS_PER_THREAD = 4096

    def __init__(self, handle: ReplayBufferHandle, data: SharedArrays, control: SharedArrays):
        self.handle = handle
        self.fields: FieldLayout = {n: (tuple(s), np.dtype(d)) for n, s, d in handle.fields}
        self.num_workers = handle.num_workers
        self.envs_per_worker = handle.envs_per_worker
        self.capacity = handle.capacity
        self._seg = data
        self._control = control
        self._count = control["count"]
        names = [*self.fields, "_row_sum"]
        # Worker w's region, {field: [capacity, ...]} views (also read by the ring spiller).
        self._data = [{name: data[name][w] for name in names} for w in range(self.num_workers)]
        # Every field of every region as one [num_workers * capacity, ...] array: row w * capacity + i.
        self._flat = {name: data[name].reshape(-1, *data[name].shape[2:]) for name in self.fields}
        self.regions = {name: data[name] for name in self.fields}  # every region as [num_workers, capacity, ...]
        self.resampled = 0  # rows redrawn because their writer may have reached them during the copy (stats)
        usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        self.gather_threads = max(1, min(4, usable))
        self._pool: ThreadPoolExecutor | None = None  # started by the first threaded gather (learner only)

    @staticmethod
    def worker_rows(capacity: int, envs_per_worker: int) -> int:
        """Rows of a worker's region asked for ``capacity``: whole env steps, at least two (the step a writer
        is writing is never sampled, see ``sample``)."""
        m = int(envs_per_worker)
        return max(-(-int(capacity) // m), 2) * m

    @classmethod
    def create(cls, fields: FieldLayout, num_workers: int, envs_per_worker: int, capacity: int,
               row_sums: bool = True) -> ReplayBuffer:
        """``row_sums=False``: commits skip the rows' checksums (~60-90 us of a 16-env cart-pole step, ~25% of a
        worker's step), for rings no :class:`~unilab_jax.runtime.replay_store.RingSpiller` reads."""
        if min(num_workers, envs_per_worker, capacity) <= 0:
            raise ValueError("num_workers, envs_per_worker and capacity must be positive")
        m, w = int(envs_per_worker), int(num_workers)
        cap = cls.worker_rows(capacity, m)
        control = SharedArrays.create({"count": ((w, 8), np.int64)}, tag="rc")
        try:
            control["count"][:] = 0
            layout = {name: ((w, cap, *shape), dt) for name, (shape, dt) in fields.items()}
            layout["_row_sum"] = ((w, cap), np.dtype(np.uint64))
            data = SharedArrays.create(layout, tag="rd")
        except BaseException:
            control.close()
            raise
        handle = ReplayBufferHandle(
            tuple((n, tuple(s), np.dtype(d).str) for n, (s, d) in fields.items()),
            w, m, cap, data.handle, control.handle, bool(row_sums),
        )
        return cls(handle, data, control)

    @classmethod
    def from_spec(cls, spec: Any, extras: Mapping[str, tuple[tuple[int, ...], Any]] | None, num_workers: int,
                  envs_per_worker: int, capacity: int) -> ReplayBuffer:
        """Built from a ``TaskSpec`` and an algorithm's ``extras(action_dim)``."""
        return cls.create(transition_layout(spec, extras), num_workers, envs_per_worker, capacity)

    @classmethod
    def attach(cls, handle: ReplayBufferHandle) -> ReplayBuffer:
        control = SharedArrays.attach(handle.control)
        data = SharedArrays.attach(handle.data)
        return cls(handle, data, control)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        self._count = None
        self._data, self._flat, self.regions = [], {}, {}
        self._seg.close()
        self._control.close()

    @property
    def segment_names(self) -> list[str]:
        return [self._control.name, self._seg.name]

    # ---- worker side --------------------------------------------------------------------------
    def count(self, worker: int) -> int:
        """Transitions worker ``worker`` has committed in total (its cursor is count % capacity)."""
        return int(self._count[worker, 0])

    def rows(self, worker: int) -> tuple[int, dict[str, np.ndarray]]:
        """(start row, ``{field: [M, ...]}`` views) of the next M rows the worker writes."""
        start = self.count(worker) % self.capacity
        region = self._data[worker]
        end = start + self.envs_per_worker
        return start, {name: region[name][start:end] for name in self.fields}

    def commit(self, worker: int) -> int:
        """Checksums the M rows at the cursor (unless the ring has no row sums), then publishes them by bumping the
        counter.

        Barriers on both sides of the publishing store: the rows before it (a reader that sees the
        counter sees them), the next step's writes after it (a reader that sees any of them sees the
        counter that announced them, see :meth:`sample`).
        """
        m = self.envs_per_worker
        if self.handle.row_sums:
            start, views = self.rows(worker)
            self._data[worker]["_row_sum"][start : start + m] = row_checksums(views, m)
        _barrier()
        new = self.count(worker) + m
        self._count[worker, 0] = new  # the single publishing store
        _barrier()
        return new

    # ---- learner side -------------------------------------------------------------------------
    def counts(self) -> np.ndarray:
        """Each worker's committed total, a copy (``set_counts``: before any worker, ``training/ring_snapshot.py``)."""
        counts = self._count[:, 0].copy()
        fence()
        return counts

    def sizes(self) -> np.ndarray:
        return np.minimum(self.counts(), self.capacity)

    def set_counts(self, counts: np.ndarray) -> None:
        self._count[:, 0] = counts

    def size(self) -> int:
        return int(self.sizes().sum())

    def sample(self, batch_size: int, rng: np.random.Generator, max_rounds: int = 100) -> dict[str, np.ndarray]:
        """``{field: [B, ...]}`` drawn uniformly (with replacement) over the valid rows, in the order drawn.

        A round (seqlock on the cursors, ``C`` = capacity, rows named by global transition index):

        1. read the counters ``c0``, barrier;
        2. draw among each region's rows ``[max(0, c0 + M - C), c0)``: committed (visible: the
           writer's barrier orders them before its counter, ours the counter before the copy) and
           not the oldest ``M`` of a full region, which a writer at ``c0`` may be overwriting now
           (also the rows a killed worker left half-written);
        3. gather them (:meth:`_gather`) straight into the output (helper threads get their part
           and report completion through the executor's locks, which order their reads between the
           caller's two barriers);
        4. barrier, read the counters ``c1``: a row ``g`` is kept only if ``g >= c1 + M - C``. The
           writer overwrites ``g`` with ``g + C``, written only after it published a counter
           ``> g + C - M``; had the copy seen any byte of that write, the barriers (the writer's
           after its counter store, ours after the copy) make ``c1`` show that counter.

        Rows that fail step 4 are redrawn in a new round (counted in ``resampled``; there are none
        unless a writer gains ``C - M`` rows on the learner during one copy); ``SlotCorruptError``
        after ``max_rounds``.
        """
        cap, m = self.capacity, self.envs_per_worker
        base = np.arange(self.num_workers, dtype=np.int64) * cap
        out = {name: np.empty((batch_size, *shape), dt) for name, (shape, dt) in self.fields.items()}
        pending: np.ndarray | None = None  # output rows still to fill (None: all of them)
        n = batch_size
        for _ in range(max_rounds):
            counts = self._count[:, 0].copy()
            _barrier()
            lo = np.maximum(counts + m - cap, 0)
            ends = np.cumsum(counts - lo)
            if ends[-1] == 0:
                raise ValueError("the replay buffer is empty")
            flat = rng.integers(0, int(ends[-1]), size=n)
            worker = np.searchsorted(ends, flat, side="right")
            g = flat + (counts - ends)[worker]  # the global transition index in its region, in [lo, counts)
            rows = base[worker] + g % cap
            dest = out if pending is None else {name: np.empty((n, *s), dt) for name, (s, dt) in self.fields.items()}
            self._gather(rows, dest)
            _barrier()
            safe = g >= self._count[:, 0].copy()[worker] + m - cap
            if pending is not None:
                for name, arr in dest.items():
                    out[name][pending[safe]] = arr[safe]
            bad = np.flatnonzero(~safe) if pending is None else pending[~safe]
            if not bad.size:
                return out
            self.resampled += int(bad.size)
            pending, n = bad, int(bad.size)
        raise SlotCorruptError(f"{n} replay rows were overwritten during every one of {max_rounds} copies")

    def read_new(self, synced: np.ndarray, fields: Iterable[str]) -> dict[str, Any]:
        """Copies the rows committed since ``synced``, for a mirror of the rings (e.g. in GPU memory).

        ``synced`` [W] holds each worker's count at the previous call (zeros at first). Returns
        ``{"slots": [n] flat row indices (worker * capacity + g % capacity), "rows": {field: [n, ...]},
        "lo": [W], "hi": [W]}``, where ``hi`` becomes the next call's ``synced``. A mirror that writes
        every call's rows to their slots holds intact copies of global rows ``[lo, hi)`` of each worker
        (the window to sample from), by :meth:`sample`'s seqlock argument: the copied range is
        ``[max(synced, c0 + M - C), c0)``; after the copy and a barrier the counters ``c1`` give
        ``lo = max(c1 + M - C, 0)``, below which a row may have been overwritten while it was copied
        (or earlier); a row at or above ``lo`` was not, and no later call rewrites its slot before ``lo``
        passes it.
        """
        cap, m = self.capacity, self.envs_per_worker
        counts = self._count[:, 0].copy()
        _barrier()
        start = np.maximum(np.maximum(np.asarray(synced, np.int64), counts + m - cap), 0)
        n = np.maximum(counts - start, 0)
        total = int(n.sum())
        worker = np.repeat(np.arange(self.num_workers, dtype=np.int64), n)
        offset = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(n) - n, n)
        slots = worker * cap + (np.repeat(start, n) + offset) % cap
        rows = {name: np.empty((total, *self.fields[name][0]), self.fields[name][1]) for name in fields}
        self._gather(slots, rows)
        _barrier()
        lo = np.maximum(self._count[:, 0].copy() + m - cap, 0)
        return {"slots": slots, "rows": rows, "lo": np.minimum(lo, counts), "hi": counts}

    def _gather(self, rows: np.ndarray, dest: Mapping[str, np.ndarray]) -> None:
        """``dest[field][i] = flat[field][rows[i]]``: one ``np.take`` per field and part of the rows.

        Whole fields per call keep each field's page-table walks together (splitting the batch into
        cache-sized chunks that visit every field measured slower); large batches are split into
        ``gather_threads`` contiguous parts, one thread each (the caller's thread takes the first).
        """
        n = rows.size
        parts = max(1, min(self.gather_threads, n // self.MIN_ROWS_PER_THREAD))

        def copy(part: int) -> None:
            sl = slice(part * n // parts, (part + 1) * n // parts)
            for name, arr in dest.items():
                np.take(self._flat[name], rows[sl], axis=0, out=arr[sl], mode="clip")  # "clip": no buffered copy

        if parts == 1:
            copy(0)
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.gather_threads - 1, thread_name_prefix="replay-gather")
        futures = [self._pool.submit(copy, part) for part in range(1, parts)]
        copy(0)
        for f in futures:
            f.result()
