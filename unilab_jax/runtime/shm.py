"""Named groups of numpy arrays in ``multiprocessing.shared_memory``.

A :class:`SharedArrays` is ONE shared-memory segment holding several numpy arrays laid out from a
``{field: (shape, dtype)}`` layout (each field 64-byte aligned, in layout order, so fields that are
adjacent in the layout are adjacent in memory). The creator builds it with :meth:`SharedArrays.create`
and hands the picklable :attr:`SharedArrays.handle` to other processes, which call
:meth:`SharedArrays.attach`.

Rules this module enforces (see DESIGN.md, "Runtime: data flow" and "Reliability checklist"):

* **Poison on creation.** Floats are NaN, signed ints -1, unsigned ints their maximum, bools True
  (a bool cannot hold a value that is not a bool; ``policy_version == -1`` is what marks unwritten
  transitions in the buffers). Unwritten data is therefore obvious.
* **Only the creator unlinks.** Python < 3.13 registers every ``SharedMemory`` it opens with the
  resource tracker, which unlinks it when the *attaching* process exits, destroying a segment that
  other processes still use. :meth:`attach` therefore opens segments without registering them
  (``track=False`` on Python >= 3.13, otherwise with the tracker's ``register`` suppressed while
  the segment is opened). The creator's registration is kept: if the creator is killed, the
  tracker process still unlinks its segments.
* **Findable names.** Every segment is called ``unilab_<creator pid>_<8 hex>_<tag>`` (short enough
  for macOS's 31-character limit), so :func:`cleanup_stale` can remove the segments of runs whose
  creator died without cleaning up (``kill -9`` of the whole process tree).
* **A clear error, not a bus error.** On Linux, a segment larger than the free space of
  ``/dev/shm`` is created fine and then kills the process with SIGBUS on first touch. Creation
  checks ``os.statvfs('/dev/shm')`` first and reserves the pages with ``posix_fallocate`` (which
  also catches a race with other processes), raising :class:`ShmSpaceError` with the sizes.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import os
import sys
import threading
import uuid
from collections.abc import Iterable, Mapping
from multiprocessing import resource_tracker, shared_memory
from typing import Any

import numpy as np

__all__ = [
    "PREFIX",
    "SharedArrays",
    "ShmHandle",
    "ShmSpaceError",
    "cleanup_stale",
    "list_segments",
    "pid_alive",
    "poison_value",
    "shm_dir",
]

PREFIX = "unilab_"
ALIGN = 64  # cache-line alignment of every field
_SHM_DIR = "/dev/shm"
# Room left free in /dev/shm beyond the requested size (other programs need some too).
_HEADROOM = 16 << 20

Layout = Mapping[str, tuple[tuple[int, ...], Any]]


class ShmSpaceError(MemoryError):
    """Not enough free space in /dev/shm for a requested segment."""


def shm_dir() -> str | None:
    """The directory where POSIX shared memory appears as files (``/dev/shm``), or None."""
    return _SHM_DIR if os.path.isdir(_SHM_DIR) else None


def poison_value(dtype: Any) -> Any:
    """The fill value marking unwritten data for ``dtype``."""
    dt = np.dtype(dtype)
    if dt.kind in "fc":
        return np.nan
    if dt.kind == "i":
        return -1
    if dt.kind == "u":
        return np.iinfo(dt).max
    if dt.kind == "b":
        return True
    raise TypeError(f"shared arrays hold numeric or bool data, not {dt}")


def _normalize_layout(layout: Layout) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    out = {}
    for name, (shape, dtype) in layout.items():
        shape = tuple(int(s) for s in shape)
        if any(s < 0 for s in shape):
            raise ValueError(f"field {name!r}: negative dimension in shape {shape}")
        dt = np.dtype(dtype)
        poison_value(dt)  # rejects object / string dtypes
        out[str(name)] = (shape, dt)
    return out


def _offsets(layout: dict[str, tuple[tuple[int, ...], np.dtype]]) -> tuple[dict[str, int], int]:
    offsets, pos = {}, 0
    for name, (shape, dt) in layout.items():
        offsets[name] = pos
        nbytes = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
        pos += -(-nbytes // ALIGN) * ALIGN
    return offsets, max(pos, ALIGN)


@dataclasses.dataclass(frozen=True)
class ShmHandle:
    """Picklable description of a segment: what :meth:`SharedArrays.attach` needs."""

    name: str
    layout: tuple[tuple[str, tuple[int, ...], str], ...]

    def layout_dict(self) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
        return {n: (tuple(s), np.dtype(d)) for n, s, d in self.layout}


_TRACKER_LOCK = threading.Lock()


def _open_untracked(name: str) -> shared_memory.SharedMemory:
    """Opens an existing segment WITHOUT registering it with the resource tracker."""
    if sys.version_info >= (3, 13):
        return shared_memory.SharedMemory(name=name, create=False, track=False)
    with _TRACKER_LOCK:
        original = resource_tracker.register

        def _skip(rname: str, rtype: str) -> None:
            if rtype != "shared_memory":
                original(rname, rtype)

        resource_tracker.register = _skip
        try:
            return shared_memory.SharedMemory(name=name, create=False)
        finally:
            resource_tracker.register = original


def _check_room(nbytes: int) -> None:
    d = shm_dir()
    if d is None:
        return
    st = os.statvfs(d)
    free = st.f_bavail * st.f_frsize
    if nbytes + _HEADROOM > free:
        raise ShmSpaceError(
            f"shared memory: need {nbytes / 2**20:.1f} MiB (+{_HEADROOM >> 20} MiB headroom) in {d} but only "
            f"{free / 2**20:.1f} MiB of {st.f_blocks * st.f_frsize / 2**20:.1f} MiB are free; use fewer envs / "
            f"slots / a smaller replay capacity, remove stale segments (unilab_jax.runtime.shm.cleanup_stale()), "
            f"or enlarge /dev/shm (docker: --shm-size)"
        )


def _new_name(tag: str) -> str:
    tag = "".join(c for c in tag if c.isalnum())[:6]
    return f"{PREFIX}{os.getpid()}_{uuid.uuid4().hex[:8]}" + (f"_{tag}" if tag else "")


class SharedArrays:
    """A group of numpy arrays in one shared-memory segment.

    ``arrays[field]`` (also ``self[field]``) are numpy views into the segment. Use as a context
    manager or call :meth:`close` (every process) and :meth:`unlink` (creator only; ``close`` does it
    for the creator).
    """

    def __init__(self, shm: shared_memory.SharedMemory, handle: ShmHandle, owner: bool):
        self._shm = shm
        self.handle = handle
        self.owner = owner
        self.name = handle.name
        layout = handle.layout_dict()
        self.offsets, self.nbytes = _offsets(layout)
        self.raw = np.ndarray((self.nbytes,), dtype=np.uint8, buffer=shm.buf)
        self.arrays: dict[str, np.ndarray] = {}
        for field, (shape, dt) in layout.items():
            self.arrays[field] = np.ndarray(shape, dtype=dt, buffer=shm.buf, offset=self.offsets[field])
        self._closed = False
        self._unlinked = False

    # ---- construction -------------------------------------------------------------------------
    @classmethod
    def create(cls, layout: Layout, tag: str = "") -> SharedArrays:
        """Creates, reserves and poison-fills a new segment for ``layout``."""
        norm = _normalize_layout(layout)
        _, nbytes = _offsets(norm)
        _check_room(nbytes)
        name = _new_name(tag)
        shm = shared_memory.SharedMemory(name=name, create=True, size=nbytes)
        try:
            fd = getattr(shm, "_fd", -1)
            if fd >= 0 and hasattr(os, "posix_fallocate"):
                try:
                    os.posix_fallocate(fd, 0, nbytes)
                except OSError as e:
                    if e.errno == errno.ENOSPC:
                        raise ShmSpaceError(
                            f"shared memory: /dev/shm ran out of space reserving {nbytes / 2**20:.1f} MiB "
                            f"for segment {name}"
                        ) from e
                    if e.errno not in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
                        raise
            handle = ShmHandle(name, tuple((n, s, d.str) for n, (s, d) in norm.items()))
            out = cls(shm, handle, owner=True)
            # A new segment reads as zeros (POSIX: a file extended by ftruncate), so the padding between fields,
            # which enters slot checksums, is zero without a pass over it: the fields' poison is the one write here
            # (a third less time for a replay ring of gigabytes than zeroing it first).
            for arr in out.arrays.values():
                arr[...] = poison_value(arr.dtype)
            return out
        except BaseException:
            with contextlib.suppress(Exception):
                shm.close()
            with contextlib.suppress(Exception):
                shm.unlink()
            raise

    @classmethod
    def attach(cls, handle: ShmHandle) -> SharedArrays:
        """Opens an existing segment (never registered with the resource tracker, never unlinked)."""
        shm = _open_untracked(handle.name)
        return cls(shm, handle, owner=False)

    # ---- access -------------------------------------------------------------------------------
    def __getitem__(self, field: str) -> np.ndarray:
        return self.arrays[field]

    def __contains__(self, field: str) -> bool:
        return field in self.arrays

    def keys(self) -> Iterable[str]:
        return self.arrays.keys()

    def byte_range(self, first: str, last: str) -> np.ndarray:
        """uint8 view from the start of field ``first`` to the aligned end of field ``last``."""
        names = list(self.arrays)
        nxt = names.index(last) + 1
        end = self.offsets[names[nxt]] if nxt < len(names) else self.nbytes
        return self.raw[self.offsets[first] : end]

    def poison(self) -> None:
        """Refills every field with its poison value."""
        for arr in self.arrays.values():
            arr[...] = poison_value(arr.dtype)

    # ---- teardown -----------------------------------------------------------------------------
    def close(self) -> None:
        """Drops this process's mapping (and unlinks, for the creator). Idempotent."""
        if self._closed:
            return
        self._closed = True
        self.arrays = {}
        self.raw = None
        try:
            self._shm.close()
        except BufferError:
            pass  # a caller still holds a view; the mapping goes when it is garbage collected
        if self.owner:
            self.unlink()

    def unlink(self) -> None:
        if self._unlinked or not self.owner:
            return
        self._unlinked = True
        with contextlib.suppress(FileNotFoundError):
            self._shm.unlink()

    def __enter__(self) -> SharedArrays:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"SharedArrays({self.name!r}, {self.nbytes} bytes, fields={list(self.offsets)}, owner={self.owner})"


# ---------------------------------------------------------------------------------------------
# Stale segments
# ---------------------------------------------------------------------------------------------
def list_segments(prefix: str = PREFIX) -> list[str]:
    """Names of the shared-memory segments in /dev/shm starting with ``prefix`` ([] without /dev/shm)."""
    d = shm_dir()
    if d is None:
        return []
    return sorted(n for n in os.listdir(d) if n.startswith(prefix))


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (on this machine; a pid of another user counts as alive)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _creator_pid(name: str, prefix: str) -> int | None:
    rest = name[len(prefix) :]
    head = rest.split("_", 1)[0]
    return int(head) if head.isdigit() else None


def cleanup_stale(prefix: str = PREFIX, dry_run: bool = False) -> list[str]:
    """Removes segments named ``<prefix><pid>_...`` whose creator process is no longer alive.

    Returns the names removed (or that would be, with ``dry_run``). Segments of live processes are
    left alone, so this is safe to call at the start of every run.
    """
    removed = []
    for name in list_segments(prefix):
        pid = _creator_pid(name, prefix)
        if pid is None or pid_alive(pid):
            continue
        removed.append(name)
        if not dry_run:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(os.path.join(_SHM_DIR, name))
    return removed
