"""Shared helpers of the kernel tests (imported by the test modules next to it)."""

from __future__ import annotations

from typing import Any

import numpy as np

from unilab_jax import xp as shim


def to_np(tree: Any) -> Any:
    """Every array leaf of ``tree`` as a numpy array (from any backend)."""
    return shim.tree_map(lambda a: a if a is None else shim.namespace(a).asnumpy(a), tree)


def put(backend: shim.Backend, tree: Any) -> Any:
    """numpy leaves of ``tree`` copied to ``backend`` as float32 (bool arrays stay bool)."""

    def leaf(a: Any) -> Any:
        if isinstance(a, np.ndarray | np.generic):
            a = np.asarray(a)
            return backend.from_numpy(a if a.dtype == np.bool_ else a.astype(np.float32))
        return a

    return shim.tree_map(leaf, tree)


def f32(*arrays: np.ndarray) -> Any:
    out = tuple(np.asarray(a, dtype=np.float32) for a in arrays)
    return out[0] if len(out) == 1 else out


def assert_close(actual: Any, expected: Any, rtol: float = 1e-5, atol: float = 1e-5) -> None:
    """Leaf-wise allclose over (possibly nested) results; a plain (nested) list of numbers as
    ``expected`` for a single array ``actual`` is compared as one array."""
    if not isinstance(actual, list | tuple | dict) and isinstance(expected, list | tuple):
        expected = np.asarray(expected, dtype=np.float64)
    a_leaves, e_leaves = shim.tree_leaves(to_np(actual)), shim.tree_leaves(to_np(expected))
    assert len(a_leaves) == len(e_leaves)
    for a, e in zip(a_leaves, e_leaves):
        np.testing.assert_allclose(np.asarray(a, dtype=np.float64), np.asarray(e, dtype=np.float64),
                                   rtol=rtol, atol=atol)


def episode_rollout(rng: np.random.Generator, t: int, b: int, p_term: float, p_trunc: float,
                    final_value_scale: float) -> tuple[np.ndarray, ...]:
    """A contiguous [t, b] rollout: ``next_values[i] == v_ext[i+1]`` unless the episode ended at ``i``,
    where the true successor is a final observation with its own value. Returns float64 ``v_ext``
    [t+1, b], ``rewards``, ``next_values`` and bool ``terminated``, ``truncated`` (disjoint)."""
    v_ext = rng.normal(size=(t + 1, b))
    rewards = rng.normal(size=(t, b))
    terminated = rng.random((t, b)) < p_term
    truncated = (rng.random((t, b)) < p_trunc) & ~terminated
    next_values = np.where(terminated | truncated, rng.normal(size=(t, b)) * final_value_scale, v_ext[1:])
    return v_ext, rewards, next_values, terminated, truncated


def episode_segments(done: np.ndarray):
    """(b, start, end, pad) of every episode segment of a [T, B] ``done`` mask, column by column; ``pad``
    left-pads a segment to length T (padding before a segment cannot reach it in a backward recursion)."""
    t_len, b_len = done.shape
    for b in range(b_len):
        ends = [t + 1 for t in range(t_len) if done[t, b]]
        for s, e in zip([0] + ends, ends + [t_len]):
            if s < e:
                yield b, s, e, t_len - (e - s)
