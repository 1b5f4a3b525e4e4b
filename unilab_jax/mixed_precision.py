"""JAX's low-precision network kernels behind ``xp.compute_dtype("bfloat16")`` (the jax backend imports this).

* ``matmul(a, b, out_dtype)``: ``a @ b`` with the operands rounded to bf16 and float32 accumulation; the
  result in ``out_dtype``. Its gradients multiply in bf16 the same way (the cotangent rounded once); the
  gradient of ``a`` comes back in ``a``'s dtype (bf16 activations get bf16 gradients, float32 inputs float32
  ones), the gradient of ``b`` (a weight) in float32.
* ``layer_norm_relu(h, b, g, o)``: ``relu(LayerNorm(h + b) * g + o)`` for a bf16 matmul output ``h``, written
  out in bf16 for the next matmul. Mean, variance and the affine map are float32; the backward pass is
  written by hand so that it keeps only ``h`` (bf16) and two float32 numbers per row (mean, 1/std) and
  recomputes the normalised values, instead of the float32 intermediates that autodiff would store.
  ``with ln_backward("pallas"):`` (this thread, at trace time; the off-policy learners' ``ln_backward`` field)
  makes the backward pass ONE fused Pallas kernel per layer (``unilab_jax.pallas_kernels``) instead of the
  XLA program of ``_ln_bwd``; shapes the kernel does not take (``h`` of rank other than 2 or 3, parameters
  that vary along the rows, a width that is not a power of two on the GPU) keep the XLA backward.

* ``conv2d(x, w, stride)``: the shim's VALID NHWC convolution with bf16 operands and a bf16 result (float32
  accumulation inside the convolution), returned as float32. Its two backward convolutions (input and weight
  gradients) take the bf16 cotangent and the saved bf16 operands and also write bf16; the input gradient comes back
  in ``x``'s dtype, the weight gradient in float32 (rounded to bf16 once, after a float32 accumulation over the
  batch and the output pixels: about 3 significant decimal digits, like every other bf16 result here).

Why a bf16 result and no ``preferred_element_type=float32``, unlike ``matmul``: XLA's GPU compiler takes mixed
precision (bf16 operands, float32 result) for dots only; a convolution with bf16 operands and a float32 result is
rewritten to a float32 convolution (its ``ConvBfloat16Support`` refuses mixed convolutions, and
``FloatNormalization`` then converts the operands up), so it would run in TF32 as before. A bf16 x bf16 -> bf16
convolution stays bf16 through XLA to cuDNN, which accumulates bf16 convolutions in float32. The encoder's next
step is the bias and the ReLU, then the next convolution rounds to bf16 anyway, so the bf16 result costs one
rounding. And no ``custom_vjp`` is needed: with a bf16 result, autodiff's transpose rules already give bf16
operands and bf16 results for both backward convolutions (the float32 upcast a ``custom_vjp`` would avoid
comes only with ``preferred_element_type=float32``); ``tests/algos/test_compute_dtype.py`` checks the lowered
program's convolutions, forward and backward.

Between two LayerNorm layers of a network, the activations then travel in bf16 forward and backward,
which halves the memory traffic of the elementwise work around each matmul: the work that bounds the
critic's update on a GPU (docs/perf/learner_scaling.md).

XLA's CPU backend has no bf16 x bf16 -> f32 dot: there the rounded operands are multiplied in float32,
which gives the same products (a product of two bf16 numbers is exact in float32).
"""

from __future__ import annotations

import contextlib
import functools
import threading
from collections.abc import Iterator
from typing import Any

import jax
import jax.numpy as jnp

F32, BF16 = jnp.float32, jnp.bfloat16
EPS = 1e-5  # LayerNorm's variance epsilon (nets._layer_norm's)
LN_BACKWARDS = ("xla", "pallas")
_LOCAL = threading.local()  # .ln_backward: the backward that layer_norm_relu traces now


@contextlib.contextmanager
def ln_backward(name: str) -> Iterator[None]:
    """Within the block (this thread, at trace time), ``layer_norm_relu``'s backward pass is ``name``'s:
    "xla" (``_ln_bwd``, the default) or "pallas" (the fused kernel, where the shapes allow it)."""
    if name not in LN_BACKWARDS:
        raise ValueError(f"ln_backward must be one of {LN_BACKWARDS}, got {name!r}")
    previous = getattr(_LOCAL, "ln_backward", "xla")
    _LOCAL.ln_backward = name
    try:
        yield
    finally:
        _LOCAL.ln_backward = previous


def unbroadcast(x: Any, shape: tuple) -> Any:
    """Sums ``x`` over the axes that broadcasting added to or widened from ``shape``."""
    x = x.sum(axis=tuple(range(x.ndim - len(shape))))
    widened = tuple(i for i, n in enumerate(shape) if n == 1 and x.shape[i] != 1)
    return x.sum(axis=widened, keepdims=True) if widened else x


def _mm(a: Any, b: Any, out_dtype: Any) -> Any:
    if jax.default_backend() == "cpu":
        return jnp.matmul(a.astype(F32), b.astype(F32)).astype(out_dtype)
    return jnp.matmul(a, b, preferred_element_type=out_dtype)


def _matmul_fwd(a: Any, b: Any, out_dtype: Any) -> tuple[Any, tuple]:
    a16, b16 = a.astype(BF16), b.astype(BF16)
    # the empty array carries a's dtype to the backward pass (residuals must be arrays)
    return _mm(a16, b16, out_dtype), (a16, b16, jnp.zeros((0,), a.dtype))


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def matmul(a: Any, b: Any, out_dtype: Any = F32) -> Any:
    return _matmul_fwd(a, b, out_dtype)[0]


def _matmul_bwd(out_dtype: Any, res: tuple, g: Any) -> tuple[Any, Any]:
    a, b, a_dtype = res
    g = g.astype(BF16)
    da = _mm(g, jnp.swapaxes(b, -1, -2), F32)
    da = unbroadcast(da, a.shape).astype(a_dtype.dtype)  # summed in float32 where a was broadcast
    db = unbroadcast(_mm(jnp.swapaxes(a, -1, -2), g, F32), b.shape)
    return da, db


matmul.defvjp(_matmul_fwd, _matmul_bwd)


def conv2d(x: Any, w: Any, stride: int) -> Any:
    """VALID NHWC/HWIO cross-correlation of ``x`` and ``w`` rounded to bf16, a bf16 result returned as float32
    (the shim's ``conv2d`` under ``compute_dtype("bfloat16")``; backward precision in the module docstring)."""
    y = jax.lax.conv_general_dilated(x.astype(BF16), w.astype(BF16), (stride, stride), "VALID",
                                     dimension_numbers=("NHWC", "HWIO", "NHWC"))
    return y.astype(F32)


def _stats(x: Any) -> tuple[Any, Any]:
    mu = jnp.mean(x, axis=-1, keepdims=True)
    var = jnp.mean(jnp.square(x - mu), axis=-1, keepdims=True)
    return mu, jax.lax.rsqrt(var + EPS)


def _ln_fwd(h: Any, b: Any, g: Any, o: Any, backward: str = "xla") -> tuple[Any, tuple]:
    x = h.astype(F32) + b
    mu, rstd = _stats(x)
    return jax.nn.relu((x - mu) * rstd * g + o).astype(BF16), (h, b, g, o, mu, rstd)


@functools.partial(jax.custom_vjp, nondiff_argnums=(4,))
def _layer_norm_relu(h: Any, b: Any, g: Any, o: Any, backward: str) -> Any:
    return _ln_fwd(h, b, g, o)[0]


def layer_norm_relu(h: Any, b: Any, g: Any, o: Any) -> Any:
    """``relu(LayerNorm(h + b) * g + o)`` in bf16, its backward the one ``ln_backward`` chose."""
    return _layer_norm_relu(h, b, g, o, getattr(_LOCAL, "ln_backward", "xla"))


def _ln_bwd(res: tuple, dy: Any) -> tuple[Any, Any, Any, Any]:
    h, b, g, o, mu, rstd = res
    xhat = (h.astype(F32) + b - mu) * rstd
    dz = jnp.where(xhat * g + o > 0, dy.astype(F32), 0.0)
    dxhat = dz * g
    # d/dx of (x - mu) * rstd, per row: rstd * (dxhat - mean(dxhat) - xhat * mean(dxhat * xhat))
    dx = rstd * (dxhat - jnp.mean(dxhat, axis=-1, keepdims=True)
                 - xhat * jnp.mean(dxhat * xhat, axis=-1, keepdims=True))
    return (dx.astype(h.dtype), unbroadcast(dx, b.shape), unbroadcast(dz * xhat, g.shape),
            unbroadcast(dz, o.shape))


def _ln_bwd_pallas(res: tuple, dy: Any) -> tuple[Any, Any, Any, Any]:
    """``_ln_bwd`` as one Pallas kernel for ``[E, B, W]`` or ``[B, W]`` ``h`` whose parameters broadcast as
    ``[E or 1, 1, W]`` (``[W]``, ``[1, W]`` ...); other shapes take ``_ln_bwd``."""
    from unilab_jax import pallas_kernels

    h, b, g, o, mu, rstd = res
    width = h.shape[-1]
    padded = [(1,) * (3 - p.ndim) + p.shape for p in (b, g, o)]
    if (h.ndim not in (2, 3) or dy.shape != h.shape or not pallas_kernels.supported(width)
            or any(p.ndim > h.ndim or s[1:] != (1, width) or s[0] not in (1, h.shape[0] if h.ndim == 3 else 1)
                   for p, s in zip((b, g, o), padded, strict=True))):
        return _ln_bwd(res, dy)
    h3, dy3, mu3, rstd3 = (a if h.ndim == 3 else a[None] for a in (h, dy, mu, rstd))
    e = h3.shape[0]
    params = [jnp.broadcast_to(p.reshape(s).astype(F32), (e, 1, width)) for p, s in zip((b, g, o), padded, strict=True)]
    dh, *partials = pallas_kernels.ln_relu_backward(h3, dy3, mu3, rstd3, *params)
    sums = [unbroadcast(jnp.sum(s, axis=1, keepdims=True).reshape((e, 1, width)[3 - h.ndim:]), p.shape)
            for s, p in zip(partials, (b, g, o), strict=True)]
    return (dh.reshape(h.shape), *sums)


def _ln_bwd_chosen(backward: str, res: tuple, dy: Any) -> tuple[Any, Any, Any, Any]:
    return (_ln_bwd_pallas if backward == "pallas" else _ln_bwd)(res, dy)


_layer_norm_relu.defvjp(_ln_fwd, _ln_bwd_chosen)
