"""Persistent replay: a disk tier under the shared-memory replay rings, crash-safe and bounded by disk.

The rings (:class:`~unilab_jax.runtime.buffers.ReplayBuffer`) stay the hot tier: workers write there
and the most recent ``replay_capacity`` transitions are sampled from RAM. Every transition is also
written through, once, to a :class:`ReplayStore` on disk (the cold tier), which keeps far more of
them (a disk budget, oldest chunks deleted first) and survives the learner being killed.
:class:`RingSpiller` moves ring rows into the store; :class:`TieredSampler` draws each minibatch
partly from the rings (``hot_fraction``) and partly from disk.

On-disk format (one directory, one writer at a time: an ``flock`` on ``LOCK``)::

    index.json       {"format": "unilab-replay-store", "version": 2, "fields": [[name, shape, dtype], ...],
                      "chunk_rows": C, "committed": R, "next_id": k, "info": {...},
                      "chunks": [[id, first_row, rows, crc32], ...],        (oldest first)
                      "sha256": SHA-256 of the rest (json.dumps(..., sort_keys=True))}
    chunk_<id>.npy   one structured .npy array of ``rows`` records, one record per transition

Rows are records (row-major), so sampling a transition reads one contiguous ~1.4 KB range (Go1)
instead of one page per field: what makes sampling from a cold page cache bearable. ``committed``
counts every row ever committed (the store's cursor, recorded in training checkpoints); a chunk's
``first_row`` places it in that sequence.

Atomicity. Rows are staged in memory until ``C`` of them fill a chunk (or :meth:`ReplayStore.flush`
is called, e.g. at a checkpoint). A chunk is written to ``chunk_<id>.npy.tmp``, fsynced, renamed
into place and the folder fsynced; then ``index.json`` is rewritten the same way (temp, fsync,
``os.replace``, folder fsync). The index is the only truth: a chunk exists once the index lists
it. Evicted chunks leave the index first and are unlinked after. Recovery at open therefore only
deletes: temp files, chunk files the index does not list (a crash between the two renames or
before an unlink), and listed chunks whose size or CRC-32 is wrong (with a warning). A SIGKILL
loses at most the staged rows of the chunk being filled. A damaged index (not JSON, its SHA-256 wrong, a
field missing) is :class:`StoreCorruptError`, naming the file and what to do; version-1 indexes (no
digest) still open after the same structural checks.
"""

from __future__ import annotations

import fcntl
import hashlib
import io
import json
import logging
import mmap
import os
import re
import threading
import weakref
import zlib
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import numpy as np

from unilab_jax.runtime.buffers import FieldLayout, ReplayBuffer, SlotCorruptError, row_checksums
from unilab_jax.runtime.durable import write_atomic
from unilab_jax.runtime.ring import fence

__all__ = ["ReplayStore", "RingSpiller", "StoreCorruptError", "StoreFormatError", "StoreLockedError",
           "TieredSampler", "default_chunk_rows"]

log = logging.getLogger(__name__)

FORMAT, VERSION = "unilab-replay-store", 2  # version 2: the index carries its SHA-256 (version 1 still opens)
INDEX, LOCK, TMP = "index.json", "LOCK", ".tmp"
_CHUNK = re.compile(r"^chunk_(\d+)\.npy$")
CHUNK_TARGET_BYTES = 16 << 20


class StoreFormatError(ValueError):
    """The directory holds a store of another format or with other fields."""


class StoreCorruptError(ValueError):
    """The store's index is damaged (unreadable, its digest wrong, fields missing); the message names it."""


class StoreLockedError(RuntimeError):
    """Another process (or another open store object) is writing this store."""


class _Chunk(NamedTuple):
    id: int
    first: int  # global index of its first row
    rows: int
    crc: int


def default_chunk_rows(fields: FieldLayout, target_bytes: int = CHUNK_TARGET_BYTES) -> int:
    """Rows per chunk so a chunk is about ``target_bytes`` (the most a crash can lose)."""
    return max(1, target_bytes // record_dtype(fields).itemsize)


def record_dtype(fields: FieldLayout) -> np.dtype:
    """Packed structured dtype of one transition (field order kept)."""
    return np.dtype([(name, np.dtype(dt), tuple(shape)) for name, (shape, dt) in fields.items()])


def _fields_json(fields: FieldLayout) -> list[list[Any]]:
    return [[name, list(shape), np.dtype(dt).str] for name, (shape, dt) in fields.items()]


def _index_digest(doc: Mapping[str, Any]) -> str:
    body = {k: v for k, v in doc.items() if k != "sha256"}
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()


def _index_problem(raw: bytes) -> tuple[dict | None, str | None]:
    """(the index document, None) or (None, what is wrong with it)."""
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as e:
        return None, f"not readable JSON ({len(raw)} bytes: {e})"
    if not isinstance(doc, dict):
        return None, "not a JSON object"
    if "sha256" in doc:
        if doc["sha256"] != _index_digest(doc):
            return None, "its SHA-256 does not match its contents (bytes changed since it was written)"
    elif doc.get("version") != 1:
        return None, "its SHA-256 digest is missing"
    if doc.get("format") != FORMAT or doc.get("version") not in (1, VERSION):
        return doc, None  # another format: StoreFormatError at the caller
    try:
        ok = (all(isinstance(doc[k], int) for k in ("chunk_rows", "committed", "next_id"))
              and isinstance(doc.get("info", {}), dict)
              and all(len(f) == 3 and isinstance(f[0], str) and isinstance(f[1], list) for f in doc["fields"])
              and all(len(c) == 4 and all(isinstance(x, int) for x in c) for c in doc["chunks"]))
        for _, _, dt in doc["fields"]:
            np.dtype(dt)
    except (KeyError, TypeError, ValueError) as e:
        return None, f"a field is missing or malformed ({type(e).__name__}: {e})"
    return (doc, None) if ok else (None, "a field is missing or malformed")


class ReplayStore:
    """The disk tier: append rows, commit them in atomic chunks, sample uniformly over what is on disk.

    Args:
      directory: the store's folder (created if missing). An existing store is reopened and
        recovered (see the module docstring); its fields must equal ``fields``.
      fields: ``{name: (shape, dtype)}`` of a row; None reopens an existing store with its own.
      chunk_rows: rows per chunk (0: the store's own, or about 16 MiB for a new store). Only new
        chunks use it.
      max_bytes: disk budget of the chunk files; the oldest chunks are deleted past it (0: none).
      verify: check every chunk's CRC-32 at open (reads the whole store once, ~3 GB/s of CPU).
      info: JSON-able record kept in a new store's index (the trainer stores task and algorithm).

    Thread-safe (one lock): the learner's sampling thread appends and samples while its main thread
    flushes at checkpoints. ``close`` does not flush: staged rows are dropped, as a crash would.
    """

    def __init__(self, directory: str, fields: FieldLayout | None = None, chunk_rows: int = 0,
                 max_bytes: int = 0, verify: bool = True, info: Mapping[str, Any] | None = None):
        self.directory = os.path.abspath(directory)
        os.makedirs(self.directory, exist_ok=True)
        self._lock = threading.RLock()
        self._lock_fd = os.open(os.path.join(self.directory, LOCK), os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self._lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(self._lock_fd)
            raise StoreLockedError(f"replay store {self.directory} is open in another process or object") from None
        # Releases the lock if the object is dropped without close() (an exception unwinding its owner).
        self._release = weakref.finalize(self, os.close, self._lock_fd)
        try:
            self.recovery: dict[str, list[str]] = {"temp_removed": [], "orphans_removed": [], "dropped": []}
            self._open(fields, chunk_rows, max_bytes, verify, info)
        except BaseException:
            self._release()
            raise

    # ---- open / recover ------------------------------------------------------------------------
    def _open(self, fields: FieldLayout | None, chunk_rows: int, max_bytes: int, verify: bool,
              info: Mapping[str, Any] | None) -> None:
        names = os.listdir(self.directory)
        for name in names:
            if name.endswith(TMP) and (name.startswith("chunk_") or name == INDEX + TMP):
                os.unlink(os.path.join(self.directory, name))
                self.recovery["temp_removed"].append(name)
        index_path = os.path.join(self.directory, INDEX)
        doc = None
        if os.path.exists(index_path):
            with open(index_path, "rb") as f:
                doc, problem = _index_problem(f.read())
            if problem:
                raise StoreCorruptError(
                    f"replay store index {index_path} is damaged: {problem}. Its chunks cannot be trusted without "
                    f"it: move {self.directory} away (or pass another --replay_dir) and --resume again; the run "
                    "continues from its checkpoint with an empty disk tier")
            if doc.get("format") != FORMAT or doc.get("version") not in (1, VERSION):
                raise StoreFormatError(f"{index_path}: not a version-1 or -{VERSION} {FORMAT} index")
            stored = {n: (tuple(s), np.dtype(d)) for n, s, d in doc["fields"]}
            if fields is not None:
                want = {n: (tuple(int(x) for x in s), np.dtype(d)) for n, (s, d) in fields.items()}
                if list(want.items()) != list(stored.items()):
                    raise StoreFormatError(f"replay store {self.directory} holds rows {_fields_json(stored)}, "
                                           f"not {_fields_json(want)}")
            fields = stored
        elif fields is None:
            raise FileNotFoundError(f"no replay store under {self.directory} (no {INDEX})")
        self.fields: FieldLayout = {n: (tuple(int(x) for x in s), np.dtype(d)) for n, (s, d) in fields.items()}
        self.dtype = record_dtype(self.fields)
        self.chunk_rows = int(chunk_rows) or int(doc["chunk_rows"] if doc else default_chunk_rows(self.fields))
        self.max_bytes = int(max_bytes)
        if self.chunk_rows <= 0 or self.max_bytes < 0:
            raise ValueError("chunk_rows must be positive and max_bytes >= 0")
        # A full chunk (records + .npy header) must fit, or the budget would evict every chunk.
        header = io.BytesIO()
        np.lib.format.write_array(header, np.empty(0, self.dtype), allow_pickle=False)
        chunk_bytes = self.chunk_rows * self.dtype.itemsize + len(header.getvalue()) + 64
        if self.max_bytes and chunk_bytes > self.max_bytes:
            raise ValueError(f"a chunk of {self.chunk_rows} rows (~{chunk_bytes} bytes) does not fit the disk "
                             f"budget of {self.max_bytes} bytes")
        self.info = dict(doc.get("info", {}) if doc else (info or {}))
        self._chunks: list[_Chunk] = [_Chunk(*map(int, c)) for c in doc["chunks"]] if doc else []
        self._committed = int(doc["committed"]) if doc else 0
        self._next_id = int(doc["next_id"]) if doc else 0
        listed = {c.id for c in self._chunks}
        for name in names:
            m = _CHUNK.match(name)
            if m and int(m.group(1)) not in listed:
                os.unlink(os.path.join(self.directory, name))
                self.recovery["orphans_removed"].append(name)
        self._maps: dict[int, np.ndarray] = {}
        self._mms: dict[int, mmap.mmap] = {}
        self._sizes: dict[int, int] = {}
        self._disk_bytes = 0
        good = []
        for c in self._chunks:
            problem = self._check(c, verify)
            if problem:
                log.warning("replay store %s: dropping chunk %d (rows %d-%d): %s", self.directory, c.id, c.first,
                            c.first + c.rows - 1, problem)
                self.recovery["dropped"].append(f"{self._name(c.id)}: {problem}")
                self._forget(c.id)
                path = self._path(c.id)
                if os.path.exists(path):
                    os.unlink(path)
            else:
                good.append(c)
                self._disk_bytes += self._sizes[c.id]
        self._chunks = good
        self._stage = np.zeros(self.chunk_rows, self.dtype)
        self._staged = 0
        evicted = self._evict()
        if doc is None or self.recovery["dropped"] or evicted or doc.get("chunk_rows") != self.chunk_rows:
            self._write_index()
        self._unlink(evicted)
        self._refresh_bounds()

    def _check(self, c: _Chunk, verify: bool) -> str | None:
        path = self._path(c.id)
        if not os.path.exists(path):
            return "file missing"
        try:
            header = np.load(path, mmap_mode="r")
        except (ValueError, OSError, EOFError) as e:
            return f"unreadable .npy ({e})"
        if header.dtype != self.dtype or header.shape != (c.rows,):
            return f"holds {header.shape} of {header.dtype}, index says ({c.rows},) rows of {self.dtype}"
        del header
        rec = self._map(c)
        if verify and zlib.crc32(rec.view(np.uint8)) != c.crc:
            return "CRC-32 mismatch"
        return None

    # ---- paths / maps --------------------------------------------------------------------------
    @staticmethod
    def _name(cid: int) -> str:
        return f"chunk_{cid:09d}.npy"

    def _path(self, cid: int) -> str:
        return os.path.join(self.directory, self._name(cid))

    def _map(self, c: _Chunk) -> np.ndarray:
        """The chunk's records, memory-mapped read-only (random access: no read-ahead)."""
        rec = self._maps.get(c.id)
        if rec is None:
            path = self._path(c.id)
            size = os.path.getsize(path)
            offset = size - c.rows * self.dtype.itemsize  # the .npy header precedes the records
            if offset <= 0:
                raise StoreFormatError(f"{path}: {size} bytes cannot hold {c.rows} rows")
            with open(path, "rb") as f:
                mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
            if hasattr(mm, "madvise") and hasattr(mmap, "MADV_RANDOM"):
                mm.madvise(mmap.MADV_RANDOM)
            rec = np.frombuffer(mm, self.dtype, count=c.rows, offset=offset)
            self._maps[c.id] = rec
            self._mms[c.id] = mm
            self._sizes[c.id] = size
        return rec

    def _forget(self, cid: int) -> None:
        """Drops a chunk's mapping (unmapped once no array made from it is alive)."""
        self._maps.pop(cid, None)
        self._mms.pop(cid, None)
        self._sizes.pop(cid, None)

    def _refresh_bounds(self) -> None:
        self._bounds = np.concatenate([[0], np.cumsum([c.rows for c in self._chunks], dtype=np.int64)])

    # ---- sizes ---------------------------------------------------------------------------------
    @property
    def committed(self) -> int:
        """Rows committed since the store was created (the cursor; evictions do not lower it)."""
        return self._committed

    @property
    def size(self) -> int:
        """Rows on disk that can be sampled."""
        return int(self._bounds[-1])

    @property
    def pending(self) -> int:
        """Rows appended but not committed yet (lost if the process dies now)."""
        return self._staged

    @property
    def num_chunks(self) -> int:
        return len(self._chunks)

    @property
    def disk_bytes(self) -> int:
        """Bytes of the chunk files on disk."""
        return self._disk_bytes

    @property
    def first_row(self) -> int:
        """Global index of the oldest row on disk (``committed`` when empty)."""
        return self._chunks[0].first if self._chunks else self._committed

    # ---- writing -------------------------------------------------------------------------------
    def append(self, rows: Mapping[str, np.ndarray]) -> int:
        """Stages ``{field: [n, ...]}`` (extra fields ignored), committing every chunk that fills;
        returns the number of rows committed so far."""
        n = len(rows[next(iter(self.fields))])
        with self._lock:
            done = 0
            while done < n:
                take = min(n - done, self.chunk_rows - self._staged)
                dst = self._stage[self._staged : self._staged + take]
                for name in self.fields:
                    dst[name] = rows[name][done : done + take]
                self._staged += take
                done += take
                if self._staged == self.chunk_rows:
                    self._commit()
            return self._committed

    def flush(self) -> int:
        """Commits the staged rows as a (short) chunk; returns the rows committed so far."""
        with self._lock:
            if self._staged:
                self._commit()
            return self._committed

    def _commit(self) -> None:
        records = self._stage[: self._staged]
        chunk = _Chunk(self._next_id, self._committed, self._staged, zlib.crc32(records.view(np.uint8)))
        write_atomic(self._path(chunk.id), lambda f: np.lib.format.write_array(f, records, allow_pickle=False),
                     binary=True, suffix=TMP)
        self._chunks.append(chunk)
        size = os.path.getsize(self._path(chunk.id))
        self._sizes[chunk.id] = size
        self._disk_bytes += size
        self._committed += chunk.rows
        self._next_id += 1
        self._staged = 0
        evicted = self._evict()
        self._write_index()  # the commit point
        self._unlink(evicted)
        self._refresh_bounds()

    def _evict(self) -> list[_Chunk]:
        """Oldest chunks past the disk budget, removed from the list (the newest always stays)."""
        out = []
        while self.max_bytes and self._disk_bytes > self.max_bytes and len(self._chunks) > 1:
            c = self._chunks.pop(0)
            self._disk_bytes -= self._sizes[c.id]
            out.append(c)
        return out

    def _unlink(self, chunks: list[_Chunk]) -> None:
        for c in chunks:
            self._forget(c.id)
            path = self._path(c.id)
            if os.path.exists(path):
                os.unlink(path)

    def _write_index(self) -> None:
        doc = {"format": FORMAT, "version": VERSION, "fields": _fields_json(self.fields),
               "chunk_rows": self.chunk_rows, "committed": self._committed, "next_id": self._next_id,
               "info": self.info, "chunks": [list(c) for c in self._chunks]}
        doc = json.loads(json.dumps(doc))  # the digest of what a reader parses (tuples, non-string keys)
        doc["sha256"] = _index_digest(doc)
        write_atomic(os.path.join(self.directory, INDEX), lambda f: json.dump(doc, f), binary=False, suffix=TMP)

    # ---- reading -------------------------------------------------------------------------------
    def sample_records(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` records drawn uniformly (with replacement) over the rows on disk."""
        with self._lock:
            total = self.size
            if total == 0:
                raise ValueError(f"the replay store {self.directory} has no committed rows")
            return self._gather(rng.integers(0, total, size=n))

    def sample(self, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        rec = self.sample_records(n, rng)
        return {name: np.ascontiguousarray(rec[name]) for name in self.fields}

    def read(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Rows with global indices ``[start, stop)``, which must all be on disk."""
        with self._lock:
            firsts = np.array([c.first for c in self._chunks], np.int64)
            rows = np.array([c.rows for c in self._chunks], np.int64)
            pos = np.arange(start, stop, dtype=np.int64)
            k = np.searchsorted(firsts, pos, side="right") - 1
            local = pos - firsts[np.maximum(k, 0)] if firsts.size else pos
            if pos.size and (not firsts.size or (k < 0).any() or (local >= rows[np.maximum(k, 0)]).any()):
                raise IndexError(f"rows [{start}, {stop}) are not all on disk")
            rec = self._gather(self._bounds[k] + local) if pos.size else np.empty(0, self.dtype)
        return {name: np.ascontiguousarray(rec[name]) for name in self.fields}

    def _gather(self, flat: np.ndarray) -> np.ndarray:
        """Records at positions ``flat`` of the concatenated on-disk rows: sorted, one gather per chunk."""
        order = np.argsort(flat, kind="stable")
        pos = flat[order]
        chunk = np.searchsorted(self._bounds, pos, side="right") - 1
        cuts = np.flatnonzero(np.diff(chunk)) + 1
        out = np.empty(flat.size, self.dtype)
        for lo, hi in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [flat.size]])):
            if hi > lo:
                k = int(chunk[lo])
                out[order[lo:hi]] = self._map(self._chunks[k])[pos[lo:hi] - self._bounds[k]]
        return out

    def evict_page_cache(self) -> bool:
        """Drops the store's pages from this process's mappings and the OS page cache (measurements of
        cold reads); False where the OS offers no way to."""
        if not hasattr(os, "posix_fadvise"):
            return False
        with self._lock:
            for mm in self._mms.values():
                if hasattr(mmap, "MADV_DONTNEED"):
                    mm.madvise(mmap.MADV_DONTNEED)
            for c in self._chunks:
                fd = os.open(self._path(c.id), os.O_RDONLY)
                try:
                    os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
                finally:
                    os.close(fd)
        return True

    def close(self) -> None:
        """Releases the lock and the mappings; staged rows are not committed (call flush first)."""
        with self._lock:
            self._maps.clear()
            self._mms.clear()
            self._staged = 0
            self._release()  # closes the lock file (once), which releases the flock

    def __enter__(self) -> ReplayStore:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class RingSpiller:
    """Copies every committed row of the replay rings into a store exactly once, worker by worker.

    Per worker a cursor (the ring's transition counter at the last read). Rows ``[cursor, count)``
    are copied out; rows the worker may overwrite while they are copied (within ``capacity - M`` of
    the counter re-read after the copy) are dropped and counted in ``lost`` (a learner too slow to
    drain the ring). The copy is checked against the rows' checksums, retried on a mismatch (the
    rows may reach this core after the counter, see ``ring.py``), as ``ReplayBuffer.sample`` does.
    A counter that went backwards (a respawned worker's ring) restarts the cursor there.
    """

    def __init__(self, ring: ReplayBuffer, store: ReplayStore, max_rounds: int = 100):
        if not ring.handle.row_sums:
            raise ValueError("a ring spiller verifies the rows' checksums: the ring needs row_sums=True")
        self.ring, self.store, self.max_rounds = ring, store, max_rounds
        self.cursors = np.zeros(ring.num_workers, np.int64)
        self.spilled = self.lost = 0

    def spill(self) -> int:
        """Appends every row committed since the last call; returns how many."""
        total = 0
        for w in range(self.ring.num_workers):
            rows = self._take(w)
            if rows is not None:
                self.store.append(rows)
                total += len(rows["_row_sum"])
        self.spilled += total
        return total

    def _take(self, w: int) -> dict[str, np.ndarray] | None:
        ring, cap, m = self.ring, self.ring.capacity, self.ring.envs_per_worker
        count = ring.count(w)
        fence()
        cursor = min(int(self.cursors[w]), count)
        lo = max(cursor, count - (cap - m))
        self.lost += lo - cursor
        self.cursors[w] = count
        if count <= lo:
            return None
        seg = ring._data[w]  # the worker's ring region (fields + "_row_sum"), only read here
        names = [*ring.fields, "_row_sum"]
        got = {name: self._copy(seg[name], lo, count, cap) for name in names}
        for _ in range(self.max_rounds):
            # Rows below ``safe`` may have been overwritten while they were copied: drop them.
            safe = max(lo, ring.count(w) + m - cap)
            if safe > lo:
                self.lost += min(safe, count) - lo
                if safe >= count:
                    return None
                got = {name: a[safe - lo :] for name, a in got.items()}
                lo = safe
            sums = got["_row_sum"]
            bad = np.flatnonzero(row_checksums({n: got[n] for n in ring.fields}, count - lo) != sums)
            if not bad.size:
                return got
            fence()
            idx = (lo + bad) % cap
            for name in names:
                got[name][bad] = seg[name][idx]
        raise SlotCorruptError(f"{bad.size} replay rows of worker {w} never matched their checksums")

    @staticmethod
    def _copy(a: np.ndarray, lo: int, hi: int, cap: int) -> np.ndarray:
        s, e = lo % cap, (hi - 1) % cap + 1
        return a[s:e].copy() if s < e else np.concatenate([a[s:], a[:e]])


class TieredSampler:
    """Minibatches drawn partly from the hot tier (the rings) and partly from the disk store.

    Each of the ``groups`` minibatches of ``batch`` rows takes ``round(hot_fraction * batch)`` rows
    from the hot tier and the rest from disk, so every gradient step sees the same mix. A tier that
    is empty gives its share to the other (disk before the first commit, the rings right after a
    restart). Both tiers are sampled uniformly with replacement.
    """

    def __init__(self, hot_size: Callable[[], int], hot_sample: Callable[[int, np.random.Generator], dict],
                 store: ReplayStore, hot_fraction: float, fields: tuple[str, ...]):
        if not 0.0 <= hot_fraction <= 1.0:
            raise ValueError(f"hot_fraction must be in [0, 1], got {hot_fraction}")
        self.hot_size, self.hot_sample, self.store = hot_size, hot_sample, store
        self.hot_fraction, self.fields = float(hot_fraction), tuple(fields)

    def hot_rows(self, batch: int) -> int:
        """Rows of each minibatch that come from the rings now."""
        hot, cold = self.hot_size() > 0, self.store.size > 0
        if not (hot or cold):
            raise ValueError("both replay tiers are empty")
        return (round(self.hot_fraction * batch) if cold else batch) if hot else 0

    def sample(self, groups: int, batch: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """``{field: [groups * batch, ...]}``, minibatch ``g`` at rows ``[g * batch, (g + 1) * batch)``."""
        k = self.hot_rows(batch)
        n = groups * batch
        hot = self.hot_sample(groups * k, rng) if k else None
        cold = self.store.sample_records(groups * (batch - k), rng) if k < batch else None
        if cold is None:
            return {name: hot[name] for name in self.fields}
        if hot is None:
            return {name: np.ascontiguousarray(cold[name]) for name in self.fields}
        out = {}
        for name in self.fields:
            shape, dt = self.store.fields[name]
            a = np.empty((groups, batch, *shape), dt)
            a[:, :k] = hot[name].reshape(groups, k, *shape)
            a[:, k:] = cold[name].reshape(groups, batch - k, *shape)
            out[name] = a.reshape(n, *shape)
        return out
