"""JAX's low-precision network kernels behind ``xp.compute_dtype("bfloat16")`` (the jax backend imports this).

* ``matmul(a, b, out_dtype)``: ``a @ b`` with the operands rounded to bf16 and float32 accumulation; the
  result in ``out_dtype``. Its gradients multiply in bf16 the same way (the cotangent rounded once); the
  gradient of ``a`` comes back in ``a``'s dtype (bf16 activations get bf16 gradients, float32 inputs float32
  ones), the gradient of ``b`` (a weight) in float32.
* ``layer_norm_relu(h, b, g, o)``: ``relu(LayerNorm(h + b) * g + o)`` for a bf16 matmul output ``h``, written
  out in bf16 for the next matmul. Mean, variance and the affine map are float32; the backward pass is
  written by hand so that it keeps only ``h`` (bf16) and two float32 numbers per row (mean, 1/std) and
  recomputes the normalised values, instead of the float32 intermediates that autodiff would store.

Between two LayerNorm layers of a network, the activations then travel in bf16 forward and backward,
which halves the memory traffic of the elementwise work around each matmul: the work that bounds the
critic's update on a GPU (docs/perf/learner_scaling.md).

XLA's CPU backend has no bf16 x bf16 -> f32 dot: there the rounded operands are multiplied in float32,
which gives the same products (a product of two bf16 numbers is exact in float32).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp

F32, BF16 = jnp.float32, jnp.bfloat16
EPS = 1e-5  # LayerNorm's variance epsilon (nets._layer_norm's)


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


def _stats(x: Any) -> tuple[Any, Any]:
    mu = jnp.mean(x, axis=-1, keepdims=True)
    var = jnp.mean(jnp.square(x - mu), axis=-1, keepdims=True)
    return mu, jax.lax.rsqrt(var + EPS)


def _ln_fwd(h: Any, b: Any, g: Any, o: Any) -> tuple[Any, tuple]:
    x = h.astype(F32) + b
    mu, rstd = _stats(x)
    return jax.nn.relu((x - mu) * rstd * g + o).astype(BF16), (h, b, g, o, mu, rstd)


@jax.custom_vjp
def layer_norm_relu(h: Any, b: Any, g: Any, o: Any) -> Any:
    return _ln_fwd(h, b, g, o)[0]


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


layer_norm_relu.defvjp(_ln_fwd, _ln_bwd)
