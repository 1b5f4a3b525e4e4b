"""The MLX backend of ``unilab_jax.xp``.

MLX already provides most Python array API names; this adapter supplies the rest and the shim's
extras (keyed random numbers, value_and_grad, compile, scan). Registered on import, with an exit hook that
frees the main thread's MLX streams before the interpreter finalizes (MLX asks every thread to call
``mx.clear_streams()`` before it ends, the main thread included; other threads: ``xp.end_thread``).
"""

from __future__ import annotations

import atexit
from collections.abc import Callable
from typing import Any

import mlx.core as mx
import numpy as np

from unilab_jax import xp as _xp


class _MlxRandom:
    """Keyed random numbers: MLX keys are uint32[2] arrays, as in JAX."""

    @staticmethod
    def key(seed: int) -> mx.array:
        return mx.random.key(int(seed))

    @staticmethod
    def split(key: mx.array, num: int = 2) -> mx.array:
        return mx.random.split(key, num)

    @staticmethod
    def normal(key: mx.array, shape: tuple = (), dtype: Any = mx.float32) -> mx.array:
        return mx.random.normal(shape=tuple(shape), dtype=dtype, key=key)

    @staticmethod
    def uniform(key, shape=(), low=0.0, high=1.0, dtype: Any = mx.float32) -> mx.array:
        return mx.random.uniform(low=low, high=high, shape=tuple(shape), dtype=dtype, key=key)

    @staticmethod
    def randint(key, shape, low, high, dtype: Any = mx.int32) -> mx.array:
        return mx.random.randint(low, high, shape=tuple(shape), dtype=dtype, key=key)


class MlxBackend(_xp.Backend):
    name = "mlx"
    ns = mx
    random = _MlxRandom()
    float32, int32, uint32, bool = mx.float32, mx.int32, mx.uint32, mx.bool_

    def owns(self, x: Any) -> bool:
        return isinstance(x, mx.array)

    # ---- array API names MLX spells differently ---------------------------------------------
    def asarray(self, x: Any, dtype: Any = None, copy: bool | None = None) -> mx.array:
        if isinstance(x, mx.array):
            return x if dtype is None else x.astype(dtype)
        if isinstance(x, np.ndarray) and x.dtype == np.float64 and dtype is None:
            x = x.astype(np.float32)  # MLX has no float64 on the GPU; keep float32 everywhere
        return mx.array(x, dtype=dtype) if dtype is not None else mx.array(x)

    def astype(self, x: mx.array, dtype: Any) -> mx.array:
        return x.astype(dtype)

    def concat(self, arrays: list, axis: int = 0) -> mx.array:
        return mx.concatenate(list(arrays), axis=axis)

    def cumulative_sum(self, x: mx.array, /, *, axis: int | None = None, dtype: Any = None,
                       include_initial: bool = False) -> mx.array:
        # mx.cumulative_sum is mx.cumsum, without the standard's include_initial (a leading zero on the axis).
        if axis is None:
            if x.ndim != 1:
                raise ValueError("cumulative_sum needs axis for arrays of rank > 1")
            axis = 0
        out = mx.cumsum(x, axis=axis, dtype=dtype)
        if not include_initial:
            return out
        shape = list(out.shape)
        shape[axis] = 1
        return mx.concatenate([mx.zeros(shape, dtype=out.dtype), out], axis=axis)

    def asnumpy(self, x: Any) -> np.ndarray:
        return np.array(x, copy=True)

    def from_numpy(self, x: Any, dtype: Any = None) -> mx.array:
        return self.asarray(np.asarray(x), dtype=dtype)

    def tree_map(self, fn: Callable, tree: Any, *rest: Any) -> Any:
        return _xp.tree_map(fn, tree, *rest)

    def stop_gradient(self, x: mx.array) -> mx.array:
        return mx.stop_gradient(x)

    def conv2d(self, x: mx.array, w: mx.array, stride: int = 1) -> mx.array:
        # The shim's weights are [kh, kw, Cin, Cout] (jax's HWIO); mx.conv2d takes [Cout, kh, kw, Cin].
        return mx.conv2d(x, mx.transpose(w, (3, 0, 1, 2)), stride=stride)

    def logsumexp(self, x: mx.array, axis: int = -1, keepdims: bool = False) -> mx.array:
        return mx.logsumexp(x, axis=axis, keepdims=keepdims)

    def softmax(self, x: mx.array, axis: int = -1) -> mx.array:
        return mx.softmax(x, axis=axis)

    def jit(self, fn: Callable, **kwargs: Any) -> Callable:
        if kwargs:
            raise TypeError(f"mx.compile takes no jit options {sorted(kwargs)}; pass state explicitly")
        return mx.compile(fn)

    def value_and_grad(self, fn: Callable, has_aux: bool = False) -> Callable:
        """Gradient w.r.t. the first argument; with ``has_aux`` fn returns (loss, aux).

        ``mx.value_and_grad`` differentiates the first output of a function returning a tuple,
        so (loss, aux) passes through unchanged in both cases.
        """
        return mx.value_and_grad(fn)

    def end_thread(self) -> None:
        _clear_streams()


def _clear_streams() -> None:
    """``mx.clear_streams()``: destroys the streams the calling thread created (the releases whose streams are
    per thread have it)."""
    clear = getattr(mx, "clear_streams", None)
    if clear is not None:
        clear()


_xp.register_backend("mlx", MlxBackend)
atexit.register(_clear_streams)
