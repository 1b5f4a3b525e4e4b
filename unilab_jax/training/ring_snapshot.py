"""The replay rings kept across an orderly stop: ``LOGDIR/replay_rings/``, which ``--resume`` copies back.

Without ``--replay_dir``, an off-policy run's replay lives only in the shared-memory rings
(:class:`~unilab_jax.runtime.buffers.ReplayBuffer`), unlinked when the run ends. At an orderly stop (the end of
training, or a SIGINT / SIGTERM the trainer handles) the trainer stops the workers, writes its last checkpoint,
then :func:`save` writes the rings here before the segments are unlinked; a ``--resume`` with the same layout
:func:`restore` s them into its new rings before any worker starts. The workers go on writing at their cursors and
every reader (host sampling, the device mirror at its first sync) finds the restored rows committed, like any
others. A kill still loses the rings (``--replay_dir`` is for that).

Format (one folder)::

    <field>.npy    one transition field of every worker's region, [workers, capacity, ...] (np.save, written
                   straight from shared memory)
    layout.json    {"format": "unilab-replay-rings", "version": 1, "task", "workers", "envs_per_worker",
                    "capacity", "fields": [[name, shape, dtype], ...], "counts": [per worker, the transitions it
                    committed in total], "env_steps": the run's env steps when saved}

The folder is written under a temporary name, every file fsynced, then renamed over the previous one
(:func:`unilab_jax.checkpoint.committed_folder`, the commit rule of npz checkpoints): it is the previous snapshot or
the whole new one. The counts are the rings' only state: a worker's cursor is its count modulo the capacity, its
valid rows the last min(count, capacity); the readers already skip the oldest env step of a full region, which a
worker killed during the stop may have been overwriting. Files are checked by size, shape and dtype, not by a
digest: one would read a GPU recipe's ~3 GB of rings once more at each stop and each restore.
"""

from __future__ import annotations

import json
import logging
import os
import time
from typing import Any

import numpy as np

from unilab_jax.checkpoint import committed_folder, remove_dead_temp_dirs
from unilab_jax.runtime.buffers import ReplayBuffer
from unilab_jax.runtime.durable import durable_file

log = logging.getLogger(__name__)

FOLDER = "replay_rings"  # under a run's log directory
FORMAT, VERSION = "unilab-replay-rings", 1
LAYOUT = "layout.json"


class SnapshotError(ValueError):
    """A snapshot that cannot go into these rings (damaged, incomplete or of another layout); the message says why."""


def keep(buffer: ReplayBuffer, logdir: str, task: str, env_steps: int) -> None:
    """The trainer's save at an orderly stop (:func:`save` into ``logdir/replay_rings``), logged. A failure (a full
    disk, say) is logged, not raised: the checkpoint is written already, and the previous snapshot, if any, stands."""
    path, t0 = os.path.join(logdir, FOLDER), time.perf_counter()
    try:
        kept = save(buffer, path, task, env_steps)
    except Exception:
        log.exception("replay rings: writing them to %s failed", path)
        return
    log.info("replay rings: %d transitions kept in %s (%.2f GB in %.1f s)", kept, path,
             sum(a.nbytes for a in buffer.regions.values()) / 1e9, time.perf_counter() - t0)


def resume(buffer: ReplayBuffer, logdir: str, task: str, env_steps: int) -> None:
    """``--resume``: :func:`restore` from ``logdir/replay_rings`` into the new rings of a run whose checkpoint is at
    ``env_steps``. No snapshot, or one that does not fit: one line says why and the rings stay empty."""
    path = os.path.join(logdir, FOLDER)
    try:
        doc = restore(buffer, path, task)
    except FileNotFoundError:
        log.info("replay rings: no snapshot in %s (the run did not stop in order); the rings start empty", path)
        return
    except Exception as e:  # damaged, incomplete, another layout: never fatal
        log.warning("replay rings: the snapshot in %s is not restored: %s; the rings start empty", path, e)
        return
    gap = (f"; the checkpoint is at env step {env_steps}: the transitions in between are lost"
           if doc.get("env_steps") != env_steps else "")
    log.info("replay rings: %d transitions restored from %s (saved at env step %s%s)", buffer.size(), path,
             doc.get("env_steps"), gap)


def layout(buffer: ReplayBuffer, task: str) -> dict[str, Any]:
    """What a snapshot of ``buffer`` records, and a restore must find equal."""
    return {"format": FORMAT, "version": VERSION, "task": task, "workers": buffer.num_workers,
            "envs_per_worker": buffer.envs_per_worker, "capacity": buffer.capacity,
            "fields": [[name, list(shape), np.dtype(dtype).str] for name, (shape, dtype) in buffer.fields.items()]}


def save(buffer: ReplayBuffer, directory: str, task: str, env_steps: int) -> int:
    """Writes ``buffer`` (no worker writing any more) to ``directory``, replacing what is there; returns the valid
    transitions kept. Temporary folders of saves killed midway (their process gone) are deleted first."""
    remove_dead_temp_dirs(os.path.dirname(os.path.abspath(directory)))
    counts = buffer.counts()
    with committed_folder(directory) as tmp:
        for name, region in buffer.regions.items():
            with durable_file(os.path.join(tmp, f"{name}.npy")) as f:
                np.save(f, region)  # a contiguous array goes to a file with one write, no copy
        with durable_file(os.path.join(tmp, LAYOUT), "w") as f:
            json.dump({**layout(buffer, task), "counts": counts.tolist(), "env_steps": int(env_steps)}, f, indent=1)
    return int(np.minimum(counts, buffer.capacity).sum())


def restore(buffer: ReplayBuffer, directory: str, task: str) -> dict[str, Any]:
    """Copies the snapshot in ``directory`` into ``buffer`` (before any worker starts) and sets its counts; returns
    the snapshot's ``layout.json``. Raises FileNotFoundError when there is no snapshot and :class:`SnapshotError`
    when it cannot be used; the counts are then left as they were (an empty ring stays empty)."""
    if not os.path.isdir(directory):
        raise FileNotFoundError(f"no replay ring snapshot in {directory}")
    path = os.path.join(directory, LAYOUT)
    try:
        with open(path, "rb") as f:
            doc = json.loads(f.read().decode("utf-8"))
    except (OSError, ValueError) as e:
        raise SnapshotError(f"{path} cannot be read ({type(e).__name__}: {e})") from e
    if not isinstance(doc, dict):
        raise SnapshotError(f"{path} is not a JSON object")
    for key, value in layout(buffer, task).items():
        if doc.get(key) != value:
            raise SnapshotError(_difference(key, doc.get(key), value))
    counts, m = doc.get("counts"), buffer.envs_per_worker
    if not (isinstance(counts, list) and len(counts) == buffer.num_workers
            and all(isinstance(c, int) and c >= 0 and c % m == 0 for c in counts)):
        raise SnapshotError(f"{path}: counts {counts!r} are not {buffer.num_workers} multiples of {m} transitions")
    regions, saved = buffer.regions, {}
    for name, region in regions.items():
        file = os.path.join(directory, f"{name}.npy")
        try:
            array = np.load(file, mmap_mode="r", allow_pickle=False)
            size = os.path.getsize(file)
        except (OSError, ValueError) as e:
            raise SnapshotError(f"{file} cannot be read ({type(e).__name__}: {e})") from e
        if array.shape != region.shape or array.dtype != region.dtype or size != array.offset + array.nbytes:
            raise SnapshotError(f"{file} holds {array.shape} {array.dtype} in {size} bytes, not {region.shape} "
                                f"{region.dtype}")
        saved[name] = array
    for name, array in saved.items():
        np.copyto(regions[name], array)  # from the page cache into shared memory
    buffer.set_counts(np.asarray(counts, np.int64))
    return doc


def _difference(key: str, saved: Any, now: Any) -> str:
    """Which item of the layout differs: for the fields, the first field that does."""
    if key == "fields" and isinstance(saved, list) and all(isinstance(f, list) and len(f) == 3 for f in saved):
        before, after = {f[0]: f[1:] for f in saved}, {f[0]: f[1:] for f in now}
        for name in [*after, *before]:
            if before.get(name) != after.get(name):
                return f"field {name!r} differs: saved {before.get(name)}, this run's {after.get(name)}"
    return f"{key} differs: saved {saved!r}, this run's {now!r}"
