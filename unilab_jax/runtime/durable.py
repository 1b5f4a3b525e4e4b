"""Crash-safe file writes, shared by the checkpoints (``checkpoint.py``), the replay store (``replay_store.py``) and the
replay rings' snapshots (``training/ring_snapshot.py``): a file is durable once written, flushed and fsynced; a
rename or a new file in a folder once that folder is fsynced too."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from typing import IO, Any


def fsync_dir(path: str) -> None:
    """Makes the entries of folder ``path`` (renames, new files) durable; a filesystem that refuses fsync on folders
    is let be (the files themselves were fsynced)."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def durable_file(path: str, mode: str = "wb") -> Iterator[IO[Any]]:
    """``open(path, mode)`` for writing, flushed and fsynced when the block ends without an error."""
    with open(path, mode) as f:
        yield f
        f.flush()
        os.fsync(f.fileno())


def write_atomic(path: str, write: Callable[[IO[Any]], None], binary: bool, suffix: str = ".tmp") -> None:
    """``write(f)`` into ``path + suffix``, fsynced, renamed over ``path``, the folder fsynced: ``path`` holds the old
    content or the new one whatever happens, and a failed write leaves no temporary file."""
    tmp = path + suffix
    try:
        with durable_file(tmp, "wb" if binary else "w") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    fsync_dir(os.path.dirname(path) or ".")
