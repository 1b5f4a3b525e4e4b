"""A versioned, double-buffered weight channel in shared memory (one writer, many readers).

The channel carries a fixed pytree template (dicts / lists / tuples of numpy arrays, e.g. the
policy parameters AND the observation-normalizer statistics, which are just more leaves). Leaves
are flattened in :func:`unilab_jax.xp.tree_paths` order into two byte buffers.

Writer (the learner), :meth:`WeightChannel.publish`::

    b = 1 - active
    buffer[b] <- leaves                      # the inactive buffer: no reader is directed to it
    header[b] <- (version, checksum(buffer[b]) mixed with version)
    fence(); active <- b                     # one aligned 8-byte store

Reader (a worker), :meth:`WeightReader.read`::

    a = active; (v, c) = header[a]; fence()
    copy <- buffer[a]; fence(); (v', c') = header[a]
    accept iff v == v' and c == c' and checksum(copy) mixed with v == c, else retry

A reader that is slow enough for the writer to come back to its buffer (two publishes during one
copy) gets a torn copy, which fails the checksum, and it simply retries; one that reads the header
before the data is visible (weak memory order) fails the same way. So a reader never returns a torn
copy, and it is never starved for long: the writer publishes at most once per learner update (ms),
while a copy of a few MB takes tens of microseconds. ``header`` words and ``active`` are single
aligned int64 words (see :mod:`unilab_jax.runtime.ring` for the memory-model argument).

Readers copy into one of two private buffers and swap only when a copy is accepted, so the tree
they handed out before stays valid if a later read fails.

Large weights (a VLA-sized policy: hundreds of MB, tens of ms per copy and checksum) would stall a
worker that reads them between two robot steps. :class:`WeightPrefetcher` reads new versions in a
background thread instead (numpy's copy and reductions release the GIL, and the worker's thread mostly
waits on its robots) and hands a finished copy over at the worker's next step; it never starts the next
copy before the worker has taken the last one, so the two private buffers are enough. On the writer's
side :class:`WeightPublisher` does the same for the learner: it writes each new version in a background
thread (the newest submitted wins), so the learner updates on while a large model is being published.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import Any

import numpy as np

from unilab_jax import xp as shim
from unilab_jax.runtime.ring import checksum, fence, wait_for
from unilab_jax.runtime.shm import ALIGN, SharedArrays, ShmHandle

__all__ = ["WeightChannel", "WeightChannelHandle", "WeightPrefetcher", "WeightReader"]

# header words: [active, -, -, -, -, -, -, -, v0, c0, -, -, -, -, -, -, v1, c1, ...]
_ACTIVE = 0
_VER = (8, 16)
_SUM = (9, 17)


@dataclasses.dataclass(frozen=True)
class _Leaf:
    path: str
    shape: tuple[int, ...]
    dtype: str
    offset: int
    nbytes: int


def _leaf_specs(template: Any) -> tuple[list[_Leaf], int]:
    specs, pos = [], 0
    for path, leaf in shim.tree_paths(template):
        a = np.asarray(leaf)
        if a.dtype.kind not in "fiub":
            raise TypeError(f"weight leaf {path!r} has dtype {a.dtype}; only numeric leaves are supported")
        specs.append(_Leaf(path, tuple(a.shape), a.dtype.str, pos, a.nbytes))
        pos += -(-a.nbytes // ALIGN) * ALIGN
    return specs, max(pos, ALIGN)


@dataclasses.dataclass(frozen=True)
class WeightChannelHandle:
    """Picklable: what a reader in another process needs."""

    shm: ShmHandle
    template: Any  # the pytree structure with zero-size placeholders (shapes live in `leaves`)
    leaves: tuple[_Leaf, ...]
    nbytes: int


def _skeleton(template: Any) -> Any:
    """The template's structure with every leaf replaced by 0 (cheap to pickle)."""
    return shim.tree_map(lambda a: 0, template)


def _unflatten(skeleton: Any, leaves: list[np.ndarray]) -> Any:
    """Inverse of ``tree_paths`` order: dict keys sorted, then lists/tuples/NamedTuples in order."""
    it = iter(leaves)

    def build(node: Any) -> Any:
        if isinstance(node, dict):
            built = {k: build(node[k]) for k in sorted(node)}
            return {k: built[k] for k in node}
        if isinstance(node, tuple) and hasattr(node, "_fields"):
            return type(node)(*(build(v) for v in node))
        if isinstance(node, list | tuple):
            return type(node)(build(v) for v in node)
        if node is None:
            return None
        return next(it)

    return build(skeleton)


class WeightChannel:
    """Writer side; created by the learner from a template pytree of numpy arrays."""

    def __init__(self, template: Any, tag: str = "w"):
        leaves, nbytes = _leaf_specs(template)
        if not leaves:
            raise ValueError("the weight template has no leaves")
        self._leaves = leaves
        self.nbytes = nbytes
        self.seg = SharedArrays.create(
            {"header": ((24,), np.int64), "data": ((2, nbytes), np.uint8)}, tag=tag
        )
        self.seg["data"][:] = 0
        self.seg["header"][:] = -1
        self.seg["header"][_ACTIVE] = 0
        self.handle = WeightChannelHandle(self.seg.handle, _skeleton(template), tuple(leaves), nbytes)
        self.version = -1

    def publish(self, tree: Any, version: int) -> None:
        """Publishes ``tree`` (same structure, shapes and dtypes as the template) as ``version``."""
        version = int(version)
        if version <= self.version:
            raise ValueError(f"weight versions must increase: got {version} after {self.version}")
        paths = shim.tree_paths(tree)
        if len(paths) != len(self._leaves):
            raise ValueError(f"weights have {len(paths)} leaves, the template {len(self._leaves)}")
        header, data = self.seg["header"], self.seg["data"]
        b = 1 - int(header[_ACTIVE])
        buf = data[b]
        for spec, (path, leaf) in zip(self._leaves, paths, strict=True):
            a = np.asarray(leaf)
            if path != spec.path or a.shape != spec.shape:
                raise ValueError(f"weight leaf {path!r} {a.shape} does not match template leaf "
                                 f"{spec.path!r} {spec.shape}")
            dst = buf[spec.offset : spec.offset + spec.nbytes].view(spec.dtype).reshape(spec.shape)
            np.copyto(dst, a, casting="same_kind")
        header[_VER[b]] = version
        header[_SUM[b]] = checksum(buf, version)
        fence()
        header[_ACTIVE] = b
        self.version = version

    def reader(self) -> WeightReader:
        """A reader on this process's own mapping (serial mode, tests)."""
        return WeightReader(self.handle, seg=self.seg)

    def close(self) -> None:
        self.seg.close()


class WeightReader:
    """Reader side (a worker); attach with ``WeightReader(handle)``."""

    def __init__(self, handle: WeightChannelHandle, seg: SharedArrays | None = None):
        self.handle = handle
        self._own = seg is None
        self.seg = SharedArrays.attach(handle.shm) if seg is None else seg
        self._bufs = [np.zeros(handle.nbytes, np.uint8), np.zeros(handle.nbytes, np.uint8)]
        self._cur = 0
        self.version = -1
        self.tree: Any = None
        self.retries = 0  # torn or not-yet-visible copies seen (for stats / tests)

    def latest_version(self) -> int:
        """The version currently published (-1: none yet); two loads, no copy."""
        header = self.seg["header"]
        return int(header[_VER[int(header[_ACTIVE])]])

    def _try_read(self) -> tuple[Any, int] | None:
        header, data = self.seg["header"], self.seg["data"]
        a = int(header[_ACTIVE])
        v, c = int(header[_VER[a]]), int(header[_SUM[a]])
        if v < 0:
            return None
        fence()
        dst = self._bufs[1 - self._cur]
        np.copyto(dst, data[a])
        fence()
        if int(header[_VER[a]]) != v or int(header[_SUM[a]]) != c or checksum(dst, v) != c:
            self.retries += 1
            return None
        self._cur = 1 - self._cur
        leaves = [dst[s.offset : s.offset + s.nbytes].view(s.dtype).reshape(s.shape) for s in self.handle.leaves]
        self.tree = _unflatten(self.handle.template, leaves)
        self.version = v
        return self.tree, v

    def read(self, min_version: int = 0, timeout: float | None = 10.0, check=None) -> tuple[Any, int]:
        """Blocks until a consistent copy with version >= ``min_version`` is read; returns (tree, version).

        The tree's arrays belong to the reader and stay valid until the next-but-one successful read.
        """

        def attempt():
            if self.latest_version() < min_version:
                return None
            got = self._try_read()
            if got is None or got[1] < min_version:
                return None
            return got

        return wait_for(attempt, timeout=timeout, check=check, what=f"weights version >= {min_version}")

    def poll(self) -> tuple[Any, int] | None:
        """Non-blocking: a newer consistent copy if one is published, else None.

        Retries a torn copy a few times (a torn copy means a publish just happened)."""
        if self.latest_version() <= self.version:
            return None
        for _ in range(100):
            got = self._try_read()
            if got is not None:
                return got
            time.sleep(0)
        return None

    def close(self) -> None:
        if self._own:
            self.seg.close()


class WeightPrefetcher:
    """Reads a :class:`WeightReader`'s new versions in a background thread; :meth:`take` hands one over.

    Owns the reader while it runs: the caller uses :meth:`take` (and the read-only ``latest_version``)
    only. A copy handed over stays valid until the next :meth:`take` returns a newer one: the thread
    waits for each copy to be taken before it reads again, into the buffer of the copy taken before.
    """

    def __init__(self, reader: WeightReader, interval_s: float = 0.002):
        if reader.tree is None:
            raise ValueError("start the prefetcher after the first read (the caller holds that copy)")
        self.reader = reader
        self.interval_s = float(interval_s)
        self._ready: tuple[Any, int] | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="weight-prefetch", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.wait(self.interval_s):
            with self._lock:
                if self._ready is not None:
                    continue
            got = self.reader.poll()
            if got is not None:
                with self._lock:
                    self._ready = got

    def take(self) -> tuple[Any, int] | None:
        """The newest finished copy (tree, version) not yet taken, or None."""
        with self._lock:
            got, self._ready = self._ready, None
        return got

    def close(self) -> None:
        """Stops the thread (the reader stays open: its owner closes it)."""
        self._stop.set()
        self._thread.join()


class WeightPublisher:
    """Runs a writer's ``publish(tree, version)`` in a background thread, so the learner does not wait
    while a large model is copied into the channel and checksummed (hundreds of MB: tens of ms).

    :meth:`submit` returns at once. Latest wins: a version submitted while an earlier one is still being
    written replaces any submitted one not yet started (that one is skipped, counted in ``skipped``;
    versions still increase, and readers only ever want the newest). :meth:`flush` waits until everything
    submitted is written; :meth:`close` writes the last submitted version, then stops the thread. The
    caller must not change a submitted tree (the trainer hands over fresh host copies). An exception
    raised by ``publish`` stops the thread and is raised again by the next submit, flush or close.
    """

    def __init__(self, publish: Any):
        self._publish = publish
        self._cond = threading.Condition()
        self._pending: tuple[Any, int] | None = None
        self._busy = False
        self._closed = False
        self._error: BaseException | None = None
        self.published_version = -1
        self.skipped = 0
        self._thread = threading.Thread(target=self._loop, name="weight-publish", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._closed:
                    self._cond.wait()
                if self._pending is None:
                    return
                (tree, version), self._pending = self._pending, None
                self._busy = True
            try:
                self._publish(tree, version)
            except BaseException as e:  # handed to the caller's next call
                with self._cond:
                    self._error, self._busy = e, False
                    self._cond.notify_all()
                return
            with self._cond:
                self._busy, self.published_version = False, version
                self._cond.notify_all()

    def _raise(self) -> None:
        if self._error is not None:
            raise RuntimeError(f"publishing weights failed: {self._error}") from self._error

    def submit(self, tree: Any, version: int) -> None:
        """Queues ``tree`` as ``version`` (replacing a queued one not yet started)."""
        with self._cond:
            self._raise()
            if self._closed:
                raise RuntimeError("the publisher is closed")
            if self._pending is not None:
                self.skipped += 1
            self._pending = (tree, int(version))
            self._cond.notify_all()

    def flush(self) -> None:
        """Waits until every submitted version is written (or the thread failed: then raises)."""
        with self._cond:
            while (self._pending is not None or self._busy) and self._error is None:
                self._cond.wait()
            self._raise()

    def close(self) -> None:
        """Writes the last submitted version, stops the thread, raises a failure of the thread."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join()
        self._raise()
