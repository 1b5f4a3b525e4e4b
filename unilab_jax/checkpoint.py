"""Whole-training-state checkpoints: orbax where it is installed, else a numpy-only format.

The training state (params, optimizer state, normalizers, RNG key, counters) is one pytree. It is
saved as a nested dict of numpy arrays (NamedTuples become dicts of their fields) plus a JSON
record of counters and configs. Restoring fills a template of the same structure: any missing,
extra or reshaped leaf is named in the error, so a checkpoint is never silently loaded into a
different network.

jax installs write orbax checkpoints; an MLX-only install (no orbax, which needs jax) writes the
``npz`` format below: one ``state.npz`` of path -> array plus ``meta.json`` per step, written
crash-safely. Either install restores either format (orbax steps need orbax), per step folder.

Damage is never restored silently: every step folder carries ``unilab_digests.json``, the size and SHA-256 of
each file the save wrote (npz: written before the folder is renamed into place; orbax: once orbax has committed
the step, at the next save, ``wait`` or ``close``). :meth:`Checkpointer.read` checks them before loading and
raises :class:`CheckpointCorruptError` naming the damaged file and the previous checkpoint to go back to; a
step without digests (written before they existed, or a process killed between orbax's commit and the digests)
restores as before, with a warning that it is unverified. :meth:`Checkpointer.remove_unfinished_saves` deletes
the temporary folders of saves that never finished (orbax's ``*.orbax-checkpoint-tmp`` after a ``kill -9``).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import shutil
import uuid
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from unilab_jax import xp as shim
from unilab_jax.runtime.durable import durable_file, fsync_dir, write_atomic
from unilab_jax.runtime.shm import pid_alive

FORMATS = ("orbax", "npz")
FORMAT_ENV = "UNILAB_CHECKPOINT_FORMAT"  # forces the format new steps are written in
NPZ_STATE, NPZ_META, NPZ_MARKER = "state.npz", "meta.json", "unilab_checkpoint.json"
_TMP_TAG, _DEL_TAG = ".unilab-tmp-", ".unilab-del-"
DIGESTS = "unilab_digests.json"  # {"version": 1, "algorithm": "sha256", "files": {path: {"bytes", "sha256"}}, "self"}
ORBAX_TMP = ".orbax-checkpoint-tmp"  # orbax's temporary step folders (renamed to <step> once committed)

log = logging.getLogger(__name__)


class CheckpointMismatchError(ValueError):
    """The checkpoint's leaves differ from the state they are restored into."""


class CheckpointCorruptError(ValueError):
    """A checkpoint file is missing, differs from the digest recorded when it was saved, or cannot be read; the
    message names the file and the previous checkpoint to resume from."""


def to_saveable(tree: Any) -> Any:
    """NamedTuples -> dicts, lists/tuples -> lists, arrays -> numpy (device arrays are fetched)."""
    if isinstance(tree, dict):
        return {str(k): to_saveable(v) for k, v in tree.items()}
    if isinstance(tree, tuple) and hasattr(tree, "_fields"):
        return {k: to_saveable(v) for k, v in zip(tree._fields, tree, strict=True)}
    if isinstance(tree, list | tuple):
        return [to_saveable(v) for v in tree]
    if tree is None:
        return None
    return shim.namespace(tree).asnumpy(tree) if not isinstance(tree, int | float) else np.asarray(tree)


def fill(template: Any, values: dict[str, np.ndarray], convert: Callable[[np.ndarray, Any], Any]) -> Any:
    """Rebuilds ``template`` with ``values`` (path -> array), checking every leaf's path and shape."""
    want = dict(shim.tree_paths(template))
    missing = sorted(set(want) - set(values))
    extra = sorted(set(values) - set(want))
    shape_bad = [f"{p}: checkpoint {tuple(np.shape(values[p]))} vs state {tuple(np.shape(want[p]))}"
                 for p in sorted(set(want) & set(values)) if np.shape(values[p]) != np.shape(want[p])]
    if missing or extra or shape_bad:
        parts = []
        if missing:
            parts.append(f"leaves missing from the checkpoint: {missing}")
        if extra:
            parts.append(f"leaves in the checkpoint but not in the state: {extra}")
        if shape_bad:
            parts.append(f"leaves with another shape: {shape_bad}")
        raise CheckpointMismatchError("checkpoint does not match the training state; " + "; ".join(parts))

    def build(node: Any, prefix: str) -> Any:
        if isinstance(node, dict):
            return {k: build(v, f"{prefix}{k}/") for k, v in node.items()}
        if isinstance(node, tuple) and hasattr(node, "_fields"):
            return type(node)(*(build(v, f"{prefix}{k}/") for k, v in zip(node._fields, node, strict=True)))
        if isinstance(node, list | tuple):
            return type(node)(build(v, f"{prefix}{i}/") for i, v in enumerate(node))
        if node is None:
            return None
        path = prefix.rstrip("/")
        return convert(np.asarray(values[path]).astype(np.asarray(shim.namespace(node).asnumpy(node)).dtype), node)

    return build(template, "")


class Checkpointer:
    """Keeps the last ``max_to_keep`` checkpoints of a run under ``directory`` (one folder per step).

    ``format``: ``"orbax"`` (needs ``orbax-checkpoint``, which needs jax), ``"npz"`` (numpy only) or
    ``None``: the ``UNILAB_CHECKPOINT_FORMAT`` environment variable if set, else orbax when it can be
    imported (jax installs) and npz otherwise (an MLX-only install). The format only decides how new
    steps are written: :meth:`restore` reads either format, detected per step folder, so a run saved
    by an MLX-only install restores under JAX and the reverse (reading an orbax step needs orbax).
    """

    def __init__(self, directory: str, max_to_keep: int = 3, format: str | None = None):  # noqa: A002
        self.directory = os.path.abspath(directory)
        self.max_to_keep = max_to_keep
        fmt = format or os.environ.get(FORMAT_ENV) or ("orbax" if _orbax_available() else "npz")
        if fmt not in FORMATS:
            raise ValueError(f"checkpoint format {fmt!r}: choose one of {FORMATS}")
        self.format = fmt
        self._mngr = None
        self._ocp = None
        self._unsealed: list[int] = []  # orbax steps saved by this object whose digests are not written yet
        os.makedirs(self.directory, exist_ok=True)
        remove_dead_temp_dirs(self.directory)
        if fmt == "orbax":
            self._ocp = _import_orbax()
            self._mngr = self._ocp.CheckpointManager(
                self.directory, options=self._ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=True),
                item_names=("state", "meta"))

    # -- steps -------------------------------------------------------------------------------------
    def all_steps(self) -> list[int]:
        """Complete steps on disk in either format (plus orbax saves still in flight), ascending."""
        steps = set(_complete_steps(self.directory))
        if self._mngr is not None:
            steps.update(int(s) for s in self._mngr.all_steps())
        return sorted(steps)

    def latest_step(self) -> int | None:
        steps = self.all_steps()
        return steps[-1] if steps else None

    def step_format(self, step: int) -> str:
        """``"npz"`` or ``"orbax"``: how ``step`` was written (FileNotFoundError if it is not complete)."""
        path = os.path.join(self.directory, str(step))
        if os.path.isfile(os.path.join(path, NPZ_MARKER)):
            return "npz"
        if os.path.isdir(path) or (self._mngr is not None and step in self._mngr.all_steps()):
            return "orbax"
        raise FileNotFoundError(f"no checkpoint of step {step} under {self.directory}")

    # -- save --------------------------------------------------------------------------------------
    def save(self, step: int, state: Any, meta: dict[str, Any]) -> None:
        """orbax: saves asynchronously, a step is only visible once committed (orbax atomicity). npz:
        saves synchronously into a temporary folder, fsyncs it and renames it to ``<step>``. Saving a
        step that exists replaces it (e.g. the final save after more updates at the same env step)."""
        if self._mngr is not None:
            ocp = self._ocp
            self.wait()  # the previous save committed and sealed first
            if step in self._mngr.all_steps():
                self._mngr.delete(step)
            self._mngr.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(to_saveable(state)),
                                                          meta=ocp.args.JsonSave(meta)), force=True)
            self._unsealed.append(int(step))
            return
        _save_npz(self.directory, int(step), to_saveable(state), meta)
        for old in _complete_steps(self.directory)[:-self.max_to_keep] if self.max_to_keep else []:
            _remove_folder(os.path.join(self.directory, str(old)))

    # -- restore -----------------------------------------------------------------------------------
    def read(self, step: int | None = None) -> tuple[int, dict[str, np.ndarray], dict[str, Any]]:
        """(step, path -> numpy array, meta) of ``step`` (default: latest), in either format."""
        step = self.latest_step() if step is None else int(step)
        if step is None:
            raise FileNotFoundError(f"no checkpoint under {self.directory}")
        fmt = self.step_format(step)
        self.wait()  # an in-flight orbax save of this object: committed and sealed before it is read
        self.verify(step)
        try:
            if fmt == "npz":
                values, meta = _load_npz(os.path.join(self.directory, str(step)))
                return step, values, meta
            return self._read_orbax(step)
        except (CheckpointCorruptError, ImportError):
            raise
        except Exception as e:  # a damaged step without digests: the library's error, with the folder named
            raise CheckpointCorruptError(self._damaged(step, "", f"cannot be read ({type(e).__name__}: {e})")) from e

    def _read_orbax(self, step: int) -> tuple[int, dict[str, np.ndarray], dict[str, Any]]:
        if self._mngr is None:
            try:
                ocp = _import_orbax()
            except ImportError as e:
                raise ImportError(f"checkpoint step {step} under {self.directory} was written by orbax; reading "
                                  f"it needs orbax-checkpoint (pip install 'unilab-jax[jax]'): {e}") from e
            # A read-only manager: max_to_keep=None, so opening it never deletes anything.
            mngr = ocp.CheckpointManager(self.directory, options=ocp.CheckpointManagerOptions(create=False),
                                         item_names=("state", "meta"))
        else:
            ocp, mngr = self._ocp, self._mngr
        try:
            out = mngr.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(),
                                                             meta=ocp.args.JsonRestore()))
        finally:
            if mngr is not self._mngr:
                mngr.close()
        values = {p: np.asarray(v) for p, v in shim.tree_paths(out["state"])}
        return step, values, dict(out["meta"])

    def restore(self, template: Any, convert: Callable[[np.ndarray, Any], Any], step: int | None = None,
                only: Sequence[str] | None = None) -> tuple[Any, dict[str, Any]]:
        """(state, meta) of ``step`` (default: latest), with leaves converted by ``convert(arr, like)``.

        ``only``: restore just these top-level entries of the saved state (e.g. ``("params", "obs_norm")``
        to act with a policy trained on another platform, whose optimizer state has another layout);
        ``template`` is then a dict of those entries. Every leaf under them must still match.
        """
        _, values, meta = self.read(step)
        if only is not None:
            names = tuple(only)
            if not isinstance(template, dict) or sorted(template) != sorted(names):
                raise ValueError(f"with only={names}, the template must be a dict with exactly those keys")
            values = {p: v for p, v in values.items() if p.split("/", 1)[0] in names}
        return fill(template, values, convert), meta

    # -- integrity ---------------------------------------------------------------------------------
    def verify(self, step: int) -> bool:
        """Checks every file of ``step`` against the digests recorded at save time: True when they match,
        False (and a warning) when the step has none (an older checkpoint); :class:`CheckpointCorruptError`
        naming the file otherwise."""
        path = os.path.join(self.directory, str(step))
        problem = _check_digests(path)
        if problem is None:
            return True
        if problem == "":
            log.warning("checkpoint %s has no %s (saved before digests were recorded, or killed right after "
                        "orbax's commit): restored unverified", path, DIGESTS)
            return False
        name, what = problem
        raise CheckpointCorruptError(self._damaged(step, name, what))

    def _damaged(self, step: int, name: str, what: str) -> str:
        """The error message for a damaged ``step``: the file, and what to do (the previous checkpoint)."""
        path = os.path.join(self.directory, str(step))
        earlier = [s for s in self.all_steps() if s < step]
        where = f"{os.path.join(path, name)} " if name else f"checkpoint {path} "
        advice = (f"To continue from the previous checkpoint, step {earlier[-1]}, move {path} out of "
                  f"{self.directory} and --resume again" if earlier else
                  f"No earlier checkpoint is left under {self.directory}: move {path} away and start the run "
                  "again without --resume")
        return f"checkpoint of step {step} is damaged: {where}{what}; it is not restored. {advice}."

    def remove_unfinished_saves(self) -> list[str]:
        """Deletes temporary folders of saves that never finished: orbax's ``<step>.orbax-checkpoint-tmp*`` (a
        process killed mid-save) and npz ones of dead processes. Call it only where no other process saves into
        this folder (``--resume``: the run that wrote it is gone). Returns the names removed."""
        self.wait()
        remove_dead_temp_dirs(self.directory)
        removed = sorted(n for n in os.listdir(self.directory) if ORBAX_TMP in n)
        for name in removed:
            path = os.path.join(self.directory, name)
            if os.path.isdir(path) and not os.path.islink(path):
                shutil.rmtree(path, ignore_errors=True)
            else:
                os.unlink(path)
        return removed

    def _seal(self) -> None:
        """Writes the digests of the orbax steps this object saved and orbax has committed since."""
        for step in self._unsealed:
            path = os.path.join(self.directory, str(step))
            if os.path.isdir(path) and not os.path.exists(os.path.join(path, DIGESTS)):
                _write_digests(path)
        self._unsealed.clear()

    def wait(self) -> None:
        if self._mngr is not None:
            self._mngr.wait_until_finished()
            self._seal()

    def close(self) -> None:
        if self._mngr is not None:
            self.wait()
            self._mngr.close()


# -- the numpy-only format -------------------------------------------------------------------------
# <directory>/<step>/state.npz   every leaf, keyed by its path ("params/actor/0/w")
# <directory>/<step>/meta.json   the JSON record passed to save
# <directory>/<step>/unilab_checkpoint.json   {"format": "npz", "version": 1, "dtypes": {path: name}}
# <directory>/<step>/unilab_digests.json      size and SHA-256 of the three above (as in orbax steps), written
#                                last; all four are fsynced in <step>.unilab-tmp-<pid>-<hex>, which is then
#                                renamed to <step> (atomic on POSIX) and the parent fsynced.
# A folder whose name is not a plain integer (a temp folder left by a crash) is never a step.


def _orbax_available() -> bool:
    try:
        _import_orbax()
    except ImportError:
        return False
    return True


def _import_orbax() -> Any:
    import orbax.checkpoint as ocp

    return ocp


def _complete_steps(directory: str) -> list[int]:
    """Integer-named step folders: npz ones carry the marker (renamed in whole); others are orbax's,
    which orbax itself only renames from its temporary name once committed."""
    try:
        names = os.listdir(directory)
    except FileNotFoundError:
        return []
    return sorted(int(n) for n in names if n.isdigit() and os.path.isdir(os.path.join(directory, n)))


def remove_dead_temp_dirs(directory: str) -> None:
    """Deletes the temporary folders of :func:`committed_folder` (npz saves) under ``directory`` whose process is
    gone (a crash mid-save); live ones are kept."""
    for name in os.listdir(directory):
        for tag in (_TMP_TAG, _DEL_TAG):
            if tag in name:
                pid = name.split(tag, 1)[1].split("-", 1)[0]
                if pid.isdigit() and not pid_alive(int(pid)):
                    shutil.rmtree(os.path.join(directory, name), ignore_errors=True)


def _encode(arr: np.ndarray) -> tuple[np.ndarray, str]:
    """(array npz can store, dtype name). Extension dtypes (bfloat16 ...) are stored as raw bits."""
    arr = np.asarray(arr, order="C")  # (ascontiguousarray would make 0-d arrays 1-d)
    if arr.dtype.kind == "V" or arr.dtype.type.__module__ != "numpy":
        return arr.view(f"u{arr.dtype.itemsize}"), arr.dtype.name
    return arr, arr.dtype.str


def _decode(arr: np.ndarray, name: str) -> np.ndarray:
    try:
        dtype = np.dtype(name)
    except TypeError:
        try:
            import ml_dtypes

            dtype = np.dtype(getattr(ml_dtypes, name))
        except (ImportError, AttributeError) as e:
            raise TypeError(f"checkpoint leaf of dtype {name!r} cannot be read without ml_dtypes") from e
    return arr if arr.dtype == dtype else arr.view(dtype)


def _save_npz(directory: str, step: int, saveable: Any, meta: dict[str, Any]) -> None:
    meta_json = json.dumps(meta, indent=2)  # fails before anything is written if meta is not JSON
    arrays, dtypes = {}, {}
    for path, leaf in shim.tree_paths(saveable):
        arrays[path], dtypes[path] = _encode(np.asarray(leaf))
    # re-saving a step replaces it, as orbax's force=True does
    with committed_folder(os.path.join(directory, str(step))) as tmp:
        with durable_file(os.path.join(tmp, NPZ_STATE)) as f:
            np.savez(f, **arrays)
        for name, text in ((NPZ_META, meta_json),
                           (NPZ_MARKER, json.dumps({"format": "npz", "version": 1, "step": step, "dtypes": dtypes}))):
            with durable_file(os.path.join(tmp, name), "w") as f:
                f.write(text)
        _write_digests(tmp)


@contextlib.contextmanager
def committed_folder(final: str) -> Iterator[str]:
    """A new temporary folder beside ``final`` (``<final>.unilab-tmp-<pid>-<hex>``) to write into; the caller fsyncs
    each file it writes. On a clean exit the folder is fsynced and replaces ``final`` (an existing one is renamed
    away, then deleted), renamed into place (atomic on POSIX), the parent fsynced: ``final`` is the old folder or
    the whole new one. On an error the temporary folder is deleted; after a crash, :func:`remove_dead_temp_dirs`
    deletes it once its process is gone."""
    parent, name = os.path.split(os.path.abspath(final))
    tmp = os.path.join(parent, f"{name}{_TMP_TAG}{os.getpid()}-{uuid.uuid4().hex[:8]}")
    os.makedirs(tmp)
    try:
        yield tmp
        fsync_dir(tmp)
        if os.path.exists(final):
            _remove_folder(final)
        os.rename(tmp, final)
        fsync_dir(parent)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _remove_folder(path: str) -> None:
    """Renames the folder away first (atomic: a step stops being one at once), then deletes it."""
    trash = f"{path}{_DEL_TAG}{os.getpid()}-{uuid.uuid4().hex[:8]}"
    os.rename(path, trash)
    shutil.rmtree(trash, ignore_errors=True)


def _load_npz(path: str) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    with open(os.path.join(path, NPZ_MARKER)) as f:
        marker = json.load(f)
    if marker.get("format") != "npz" or marker.get("version") != 1:
        raise ValueError(f"{path}: unknown checkpoint format {marker!r}")
    dtypes = marker.get("dtypes", {})
    with np.load(os.path.join(path, NPZ_STATE), allow_pickle=False) as z:
        values = {k: _decode(z[k], dtypes.get(k, z[k].dtype.str)) for k in z.files}
    with open(os.path.join(path, NPZ_META)) as f:
        meta = json.load(f)
    return values, meta


# -- digests ---------------------------------------------------------------------------------------
def _sha256(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _files(path: str) -> list[str]:
    """Every regular file under the step folder ``path`` (relative, sorted), the digest files excluded."""
    out = []
    for root, dirs, names in os.walk(path):
        dirs.sort()
        for name in names:
            rel = os.path.relpath(os.path.join(root, name), path)
            if rel not in (DIGESTS, DIGESTS + ".tmp"):
                out.append(rel)
    return sorted(out)


def _self_digest(files: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(files, sort_keys=True).encode()).hexdigest()


def _write_digests(path: str) -> None:
    """``path/DIGESTS``: size and SHA-256 of every file of the step folder ``path``, written crash-safely."""
    files = {rel: {"bytes": os.path.getsize(os.path.join(path, rel)), "sha256": _sha256(os.path.join(path, rel))}
             for rel in _files(path)}
    doc = {"version": 1, "algorithm": "sha256", "files": files, "self": _self_digest(files)}
    write_atomic(os.path.join(path, DIGESTS), lambda f: json.dump(doc, f, indent=1, sort_keys=True), binary=False)


def _check_digests(path: str) -> tuple[str, str] | str | None:
    """None: every file matches its digest; ``""``: no digests; else (file, what is wrong with it)."""
    record = os.path.join(path, DIGESTS)
    if not os.path.isfile(record):
        return ""
    try:
        with open(record, "rb") as f:
            doc = json.loads(f.read().decode("utf-8"))
        files = doc["files"]
        ok = doc.get("algorithm") == "sha256" and doc["self"] == _self_digest(files)
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        return DIGESTS, f"(the digests recorded at save time) cannot be read ({type(e).__name__}: {e})"
    if not ok:
        return DIGESTS, "(the digests recorded at save time) does not match its own checksum"
    for rel, want in sorted(files.items()):
        full = os.path.join(path, rel)
        if not os.path.isfile(full):
            return rel, "is missing"
        size = os.path.getsize(full)
        if size != want["bytes"]:
            return rel, f"has {size} bytes, {want['bytes']} when it was saved (truncated or overwritten)"
        if _sha256(full) != want["sha256"]:
            return rel, "differs from the SHA-256 digest recorded when it was saved (its bytes changed)"
    return None
