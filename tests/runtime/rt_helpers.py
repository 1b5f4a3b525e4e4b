"""Child-process bodies for the runtime stress tests (importable by spawned processes)."""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import time

import numpy as np

from unilab_jax.runtime.buffers import ReplayBuffer, TrajectoryBuffer
from unilab_jax.runtime.shm import SharedArrays
from unilab_jax.runtime.weights import WeightChannel, WeightReader

# A slot layout with every dtype the buffers use.
PATTERN_FIELDS = {
    "a": ((64,), np.dtype(np.float32)),
    "b": ((), np.dtype(np.int64)),
    "c": ((3,), np.dtype(np.int32)),
    "d": ((), np.dtype(bool)),
    "e": ((17,), np.dtype(np.float32)),
}


def weight_tree(value: float) -> dict:
    """A tree of ~200k floats (so copies take long enough for a writer to race them)."""
    return {
        "actor": [{"w": np.full((48, 512), value, np.float32), "b": np.full((512,), value, np.float32)},
                  {"w": np.full((512, 256), value, np.float32), "b": np.full((256,), value, np.float32)}],
        "log_std": np.full((12,), value, np.float32),
        "obs_norm": {"mean": np.full((48,), value, np.float32), "var": np.full((48,), value, np.float32),
                     "count": np.full((), value, np.float32)},
    }


def weights_writer(handle_box, ctl_handle, max_seconds: float) -> None:
    """Publishes constant trees with value == version as fast as it can until told to stop."""
    # The channel is created by the writer itself (it is the owner) and its handle sent back.
    ch = WeightChannel(weight_tree(0.0))
    ctl = SharedArrays.attach(ctl_handle)
    handle_box.put(ch.handle)
    version = 0
    deadline = time.monotonic() + max_seconds
    try:
        while not ctl["flags"][0] and time.monotonic() < deadline:
            ch.publish(weight_tree(float(version)), version)
            ctl["flags"][1] = version
            version += 1
    finally:
        ctl["flags"][2] = 1  # writer done; keep the segment until the reader is done
        while not ctl["flags"][3] and time.monotonic() < deadline + 30:
            time.sleep(0.01)
        ch.close()
        ctl.close()


def weights_reader(handle_box, ctl_handle, n_reads: int, result_queue) -> None:
    """Reads ``n_reads`` times; records torn copies (leaves not all equal to the version)."""
    handle = handle_box.get()
    ctl = SharedArrays.attach(ctl_handle)
    reader = WeightReader(handle)
    torn, non_monotone, distinct, last = 0, 0, set(), -1
    for _ in range(n_reads):
        tree, version = reader.read(min_version=0, timeout=30.0)
        for leaf in _leaves(tree):
            if not np.all(leaf == np.float32(version)):
                torn += 1
                break
        if version < last:
            non_monotone += 1
        last = version
        distinct.add(version)
        reader.version = -1  # force a full re-read next time (read() otherwise returns the newest)
    ctl["flags"][0] = 1  # stop the writer
    result_queue.put({"torn": torn, "non_monotone": non_monotone, "distinct": len(distinct),
                      "retries": reader.retries, "reads": n_reads})
    reader.close()
    ctl["flags"][3] = 1
    ctl.close()


def _leaves(tree):
    if isinstance(tree, dict):
        for k in sorted(tree):
            yield from _leaves(tree[k])
    elif isinstance(tree, list):
        for x in tree:
            yield from _leaves(x)
    else:
        yield tree


def fill_pattern(views: dict, value: int) -> None:
    for arr in views.values():
        if arr.dtype == bool:
            arr[...] = bool(value % 2)
        else:
            arr[...] = value


def pattern_ok(views: dict, value: int) -> bool:
    for arr in views.values():
        want = bool(value % 2) if arr.dtype == bool else arr.dtype.type(value)
        if not np.all(arr == want):
            return False
    return True


def slot_producer(handle, worker: int, n_slots: int, timeout: float) -> None:
    """Fills slot after slot with the pattern ``value == publication index`` and publishes it."""
    buf = TrajectoryBuffer.attach(handle)
    try:
        for i in range(n_slots):
            slot = buf.acquire(worker, timeout=timeout)
            views = buf.slot(worker, slot)
            fill_pattern(views, i)
            buf.publish(worker, slot)
    finally:
        buf.close()


# ---- replay rings: every field of a row holds the row's value (worker * ROW_STRIDE + global index) -----
# float32 fields hold the value exactly below 2**24, which workers 0-2 stay under; a racing writer writes
# ~10^5 rows/s, so it stops short of the stride (an index past it would read as the next worker's row).
ROW_STRIDE = 4_000_000


def replay_value(worker: int, index: np.ndarray) -> np.ndarray:
    index = np.asarray(index, dtype=np.int64)
    if index.size and index.max() >= ROW_STRIDE:
        raise ValueError(f"row index {index.max()} does not fit the pattern's stride {ROW_STRIDE}")
    return worker * ROW_STRIDE + index


def replay_worker_and_index(value: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return value // ROW_STRIDE, value % ROW_STRIDE


def write_replay_step(buf: ReplayBuffer, worker: int) -> None:
    """One env step of ``worker``: its next M rows, each filled with its value, committed."""
    value = replay_value(worker, buf.count(worker) + np.arange(buf.envs_per_worker))
    _, views = buf.rows(worker)
    for arr in views.values():
        v = value.reshape(-1, *[1] * (arr.ndim - 1))
        arr[...] = v % 2 == 1 if arr.dtype == bool else v
    buf.commit(worker)


def replay_rows_ok(batch: dict) -> np.ndarray:
    """Per sampled row: True if every field holds the same value (the int64 field ``b``), i.e. not torn."""
    value = batch["b"]
    ok = np.ones(value.shape, dtype=bool)
    for arr in batch.values():
        v = value.reshape(-1, *[1] * (arr.ndim - 1))
        want = v % 2 == 1 if arr.dtype == bool else v
        ok &= (arr == want).reshape(len(value), -1).all(axis=1)
    return ok


@contextlib.contextmanager
def racing_replay_writer(buf: ReplayBuffer, worker: int = 0, laps: int = 2):
    """A spawned process writing ``worker``'s region of ``buf`` as fast as it can (``replay_writer``),
    started and already ``laps`` times round the ring when the body runs; stopped (killed if it hangs)
    after. Yields the process."""
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    proc = ctx.Process(target=replay_writer, args=(buf.handle, worker, stop, 60.0))
    try:
        proc.start()
        deadline = time.monotonic() + 30
        while buf.count(worker) < laps * buf.capacity:
            assert proc.is_alive() and time.monotonic() < deadline, f"writer not running (exit {proc.exitcode})"
            time.sleep(0.001)
        yield proc
        assert proc.is_alive(), f"writer died (exit {proc.exitcode})"
    finally:
        stop.set()
        if proc.pid is not None:
            proc.join(10)
            if proc.is_alive():
                proc.kill()
                proc.join()


def replay_writer(handle, worker: int, stop, timeout: float) -> None:
    """Writes pattern steps into region ``worker`` as fast as it can until ``stop`` is set (idles once its
    row indices would leave the pattern's stride)."""
    buf = ReplayBuffer.attach(handle)
    deadline = time.monotonic() + timeout
    try:
        while not stop.is_set() and time.monotonic() < deadline:
            if buf.count(worker) + buf.envs_per_worker > ROW_STRIDE:
                stop.wait(deadline - time.monotonic())
                break
            write_replay_step(buf, worker)
    finally:
        buf.close()
