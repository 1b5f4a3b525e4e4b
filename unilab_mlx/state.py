"""Learner states between backends: a JAX (or numpy) state into an MLX one, and back to numpy.

Used by both MLX learners (PPO, off-policy) and their parity tests. Imports mlx and numpy only.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import mlx.core as mx
import numpy as np

from unilab_jax import xp as shim


def _child(src: Any, key: Any, path: str) -> Any:
    if isinstance(key, str):
        if isinstance(src, Mapping):
            if key not in src:
                raise KeyError(f"{path}{key}: missing in the source state (has {sorted(src)})")
            return src[key]
        if hasattr(src, key):  # a NamedTuple (e.g. an optax state) or any object with that field
            return getattr(src, key)
        raise KeyError(f"{path}{key}: missing in the source state ({type(src).__name__})")
    return src[key]


def _fill(like: Any, src: Any, path: str = "") -> Any:
    if isinstance(like, dict):
        return {k: _fill(v, _child(src, k, path), f"{path}{k}/") for k, v in like.items()}
    if isinstance(like, tuple) and hasattr(like, "_fields"):
        return type(like)(*(_fill(v, _child(src, f, path), f"{path}{f}/")
                            for f, v in zip(like._fields, like)))
    if isinstance(like, list | tuple):
        if len(src) != len(like):
            raise ValueError(f"{path or '/'}: length {len(src)} in the source state, {len(like)} expected")
        return type(like)(_fill(v, src[i], f"{path}{i}/") for i, v in enumerate(like))
    a = np.asarray(src)
    if tuple(a.shape) != tuple(like.shape):
        raise ValueError(f"{path.rstrip('/')}: shape {a.shape} in the source state, "
                         f"{tuple(like.shape)} expected")
    return mx.array(a).astype(like.dtype)


def state_from_numpy(tree: Any, like: Any) -> Any:
    """``tree`` (a learner state of numpy or JAX arrays, e.g. a JAX learner's) as an MLX state.

    ``like`` is an MLX state giving structure, shapes and dtypes (``learner.init(key)``). The source is
    read by name: dict keys and NamedTuple fields (so optax's ``InjectStatefulHyperparamsState`` /
    ``ScaleByAdamState`` / ``EmptyState`` map onto ``unilab_mlx.optim``'s dicts; extra source fields
    such as optax's empty ``hyperparams_states`` are ignored). Leaves go through ``np.asarray``, so no
    jax import is needed here. A missing field or a shape mismatch raises, naming the leaf.
    """
    out = _fill(like, tree)
    mx.eval(out)
    return out


def state_to_numpy(state: Any) -> Any:
    """Every mx array leaf of ``state`` as a numpy array (same structure)."""
    return shim.tree_map(lambda a: np.array(a) if isinstance(a, mx.array) else a, state)
