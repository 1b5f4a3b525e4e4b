"""Whole-training-state checkpoints with orbax.

The training state (params, optimizer state, normalizers, RNG key, counters) is one pytree. It is
saved as a nested dict of numpy arrays (NamedTuples become dicts of their fields) plus a JSON
record of counters and configs. Restoring fills a template of the same structure: any missing,
extra or reshaped leaf is named in the error, so a checkpoint is never silently loaded into a
different network.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np

from unilab_jax import xp as shim


class CheckpointMismatchError(ValueError):
    """The checkpoint's leaves differ from the state they are restored into."""


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
    """Keeps the last ``max_to_keep`` checkpoints of a run under ``directory``."""

    def __init__(self, directory: str, max_to_keep: int = 3):
        import orbax.checkpoint as ocp

        self._ocp = ocp
        self.directory = os.path.abspath(directory)
        self._mngr = ocp.CheckpointManager(
            self.directory, options=ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=True),
            item_names=("state", "meta"))

    def latest_step(self) -> int | None:
        return self._mngr.latest_step()

    def save(self, step: int, state: Any, meta: dict[str, Any]) -> None:
        """Saves asynchronously; a step is only visible once fully committed (orbax atomicity)."""
        ocp = self._ocp
        self._mngr.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(to_saveable(state)),
                                                      meta=ocp.args.JsonSave(meta)), force=True)

    def restore(self, template: Any, convert: Callable[[np.ndarray, Any], Any],
                step: int | None = None) -> tuple[Any, dict[str, Any]]:
        """(state, meta) of ``step`` (default: latest), with leaves converted by ``convert(arr, like)``."""
        ocp = self._ocp
        step = self.latest_step() if step is None else step
        if step is None:
            raise FileNotFoundError(f"no checkpoint under {self.directory}")
        out = self._mngr.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(),
                                                               meta=ocp.args.JsonRestore()))
        values = {p: np.asarray(v) for p, v in shim.tree_paths(out["state"])}
        return fill(template, values, convert), dict(out["meta"])

    def wait(self) -> None:
        self._mngr.wait_until_finished()

    def close(self) -> None:
        self._mngr.wait_until_finished()
        self._mngr.close()
