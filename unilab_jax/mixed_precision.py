"""JAX's low-precision network kernels behind ``xp.compute_dtype("bfloat16")`` (the jax backend imports this).

* ``matmul(a, b, out_dtype)``: ``a @ b`` with the operands rounded to bf16 and float32 accumulation; the
  result in ``out_dtype``. Its gradients multiply in bf16 the same way (the cotangent rounded once); the
  gradient of ``a`` comes back in ``a``'s dtype (bf16 activations get bf16 gradients, written by the GEMM as
  bf16; float32 inputs float32 ones), the gradient of ``b`` (a weight) in float32.
* ``layer_norm_relu(h, b, g, o)``: ``relu(LayerNorm(h + b) * g + o)`` for a bf16 matmul output ``h``, written
  out in bf16 for the next matmul. Mean, variance and the affine map are float32; the backward pass is
  written by hand so that it keeps only ``h`` (bf16) and two float32 numbers per row (mean, 1/std) and
  recomputes the normalised values, instead of the float32 intermediates that autodiff would store.
  ``with ln_kernels(forward="pallas", backward="pallas"):`` (this thread, at trace time; the off-policy
  learners' ``ln_forward`` / ``ln_backward`` fields) makes either pass ONE fused Pallas kernel per layer
  (``unilab_jax.pallas_kernels``) instead of XLA's program (``_ln_fwd``'s, ``_ln_bwd``'s); shapes the kernels do
  not take (``h`` of rank other than 2 or 3, parameters that vary along the rows, a width that is not a power of
  two on the GPU) keep XLA's. The Pallas forward also keeps the matmul's result in bf16: given the float32
  statistics of ``h.astype(float32)``, XLA widens the bf16 matmul to a float32 result instead.

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
LN_KERNELS = ("xla", "pallas")
_LOCAL = threading.local()  # .kernels: the (forward, backward) that layer_norm_relu traces now


@contextlib.contextmanager
def ln_kernels(forward: str = "xla", backward: str = "xla") -> Iterator[None]:
    """Within the block (this thread, at trace time), ``layer_norm_relu``'s forward and backward passes are
    "xla" (``_ln_fwd``'s and ``_ln_bwd``'s programs, the default) or "pallas" (the fused kernels, where the shapes
    allow them)."""
    for what, name in (("ln_forward", forward), ("ln_backward", backward)):
        if name not in LN_KERNELS:
            raise ValueError(f"{what} must be one of {LN_KERNELS}, got {name!r}")
    previous = getattr(_LOCAL, "kernels", ("xla", "xla"))
    _LOCAL.kernels = (forward, backward)
    try:
        yield
    finally:
        _LOCAL.kernels = previous


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
    # An input shared by an ensemble ([B, in] @ [E, in, out]) is broadcast to [E, B, in] first: a batched GEMM writes
    # [E, B, out] as it is laid out; jnp.matmul's own broadcast is one [B, in] @ [in, E * out] GEMM whose [B, E, out]
    # result XLA then transposes (a pass over the widest activation: H100 trace, docs/perf/learner_scaling.md 16).
    shared = a16.ndim < b16.ndim
    lhs = jnp.broadcast_to(a16, b16.shape[:-2] + a16.shape[-2:]) if shared and a16.ndim >= 2 else a16
    # the empty array carries a's dtype to the backward pass (residuals must be arrays)
    return _mm(lhs, b16, out_dtype), (a16, b16, jnp.zeros((0,), a.dtype))


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def matmul(a: Any, b: Any, out_dtype: Any = F32) -> Any:
    return _matmul_fwd(a, b, out_dtype)[0]


def _matmul_bwd(out_dtype: Any, res: tuple, g: Any) -> tuple[Any, Any]:
    a, b, a_dtype = res
    g = g.astype(BF16)
    bt = jnp.swapaxes(b, -1, -2)
    if a_dtype.dtype == BF16 and a.shape == g.shape[:-1] + a.shape[-1:]:  # a bf16 result straight from the GEMM
        da = _mm(g, bt, BF16)
    else:  # summed in float32 where a was broadcast
        da = unbroadcast(_mm(g, bt, F32), a.shape).astype(a_dtype.dtype)
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


def _pallas_params(h: Any, b: Any, g: Any, o: Any) -> list | None:
    """``b, g, o`` as the kernels' float32 ``[E, 1, W]`` for ``h`` ``[E, B, W]`` or ``[B, W]`` (E = 1), or None
    where the kernels do not take these shapes (other ranks, parameters varying along the rows, a width the GPU
    lowering refuses)."""
    from unilab_jax import pallas_kernels

    width = h.shape[-1]
    padded = [(1,) * (3 - p.ndim) + p.shape for p in (b, g, o)]
    if (h.ndim not in (2, 3) or not pallas_kernels.supported(width)
            or any(p.ndim > h.ndim or s[1:] != (1, width) or s[0] not in (1, h.shape[0] if h.ndim == 3 else 1)
                   for p, s in zip((b, g, o), padded, strict=True))):
        return None
    e = h.shape[0] if h.ndim == 3 else 1
    return [jnp.broadcast_to(p.reshape(s).astype(F32), (e, 1, width)) for p, s in zip((b, g, o), padded, strict=True)]


def _ln_fwd_pallas(h: Any, b: Any, g: Any, o: Any) -> tuple[Any, Any, Any] | None:
    from unilab_jax import pallas_kernels

    params = _pallas_params(h, b, g, o)
    if params is None:
        return None
    y, mu, rstd = pallas_kernels.ln_relu_forward(h if h.ndim == 3 else h[None], *params, eps=EPS)
    return (y, mu, rstd) if h.ndim == 3 else (y[0], mu[0], rstd[0])


def _ln_fwd(h: Any, b: Any, g: Any, o: Any, forward: str = "xla", backward: str = "xla") -> tuple[Any, tuple]:
    fused = _ln_fwd_pallas(h, b, g, o) if forward == "pallas" else None
    if fused is not None:
        y, mu, rstd = fused
        return y, (h, b, g, o, mu, rstd)
    x = h.astype(F32) + b
    mu, rstd = _stats(x)
    return jax.nn.relu((x - mu) * rstd * g + o).astype(BF16), (h, b, g, o, mu, rstd)


@functools.partial(jax.custom_vjp, nondiff_argnums=(4, 5))
def _layer_norm_relu(h: Any, b: Any, g: Any, o: Any, forward: str, backward: str) -> Any:
    return _ln_fwd(h, b, g, o, forward)[0]


def layer_norm_relu(h: Any, b: Any, g: Any, o: Any) -> Any:
    """``relu(LayerNorm(h + b) * g + o)`` in bf16, its forward and backward the ones ``ln_kernels`` chose."""
    return _layer_norm_relu(h, b, g, o, *getattr(_LOCAL, "kernels", ("xla", "xla")))


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
    params = _pallas_params(h, b, g, o) if dy.shape == h.shape else None
    if params is None:
        return _ln_bwd(res, dy)
    h3, dy3, mu3, rstd3 = (a if h.ndim == 3 else a[None] for a in (h, dy, mu, rstd))
    e, width = h3.shape[0], h.shape[-1]
    dh, *partials = pallas_kernels.ln_relu_backward(h3, dy3, mu3, rstd3, *params)
    sums = [unbroadcast(jnp.sum(s, axis=1, keepdims=True).reshape((e, 1, width)[3 - h.ndim:]), p.shape)
            for s, p in zip(partials, (b, g, o), strict=True)]
    return (dh.reshape(h.shape), *sums)


def _ln_bwd_chosen(forward: str, backward: str, res: tuple, dy: Any) -> tuple[Any, Any, Any, Any]:
    return (_ln_bwd_pallas if backward == "pallas" else _ln_bwd)(res, dy)


_layer_norm_relu.defvjp(_ln_fwd, _ln_bwd_chosen)
