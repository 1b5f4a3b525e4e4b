"""Fused Pallas kernels for ``mixed_precision.layer_norm_relu``: its forward pass (``ln_forward="pallas"``) and its
backward pass (``ln_backward="pallas"``).

``ln_relu_forward(h, b, g, o)`` takes an ensemble's ``[E, B, W]`` bf16 matmul output ``h`` and the float32
parameters broadcast to ``[E, 1, W]``; it returns ``y = relu(LayerNorm(h + b) * g + o)`` in bf16 and the per-row
float32 mean and 1/std (``[E, B, 1]``) that the backward pass reads. ONE kernel per layer, the same grid and chunks
as the backward's: it reads ``h`` once (bf16) and writes ``y`` once, where XLA's program reads a float32 matmul
output (XLA widens the matmul's bf16 result to the float32 that the statistics are taken in) and, in its fusions,
re-reads it for the statistics.

``ln_relu_backward(h, dy, mu, rstd, b, g, o)`` takes an ensemble's ``[E, B, W]`` bf16 matmul output ``h`` and
cotangent ``dy``, the forward pass's per-row float32 mean and 1/std (``[E, B, 1]``) and the float32 parameters
broadcast to ``[E, 1, W]``; it returns ``dh`` (``[E, B, W]``, ``h``'s dtype) and three ``[E, n_blocks, W]``
float32 partial sums over row blocks (of ``dx``, ``dz * xhat`` and ``dz``: the gradients of the bias, gain and
offset before their batch sums, which the caller finishes with a small ``jnp.sum``).

The backward, ONE kernel per layer: a grid over ``(E, row blocks)``, each program walking its ``ROWS_PER_BLOCK``
rows in chunks of ``chunk`` rows (the whole width ``W`` in each): it reads ``h`` and ``dy`` once, recomputes the
normalised values from the saved statistics, takes the two row means of the LayerNorm gradient, writes ``dx`` in
bf16 and keeps the three column sums in float32 registers across its chunks. ``B`` not a multiple of the block: the rows
are padded with zeros (``dy = 0`` and ``rstd = 0`` there, so a padded row's ``dx``, ``dz`` and ``xhat`` are exactly
zero and add nothing to the partial sums) and ``dh`` is cut back to ``B`` rows.

On the CPU both run in Pallas's interpreter (the tests); elsewhere through Pallas's Triton lowering, asked for by
their compiler parameters (jax's default GPU lowering, Mosaic GPU, stages whole blocks in shared memory), whose
blocks must have power-of-two sizes: ``supported`` says whether a width can take these kernels.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pl_triton

F32 = jnp.float32
ROWS_PER_BLOCK = 64  # rows per program: E * B / 64 programs (256 for FastSAC Go1's E=2, B=8192)
CHUNK_ELEMENTS = 8192  # elements of one chunk (rows x W) held in registers at a time
NUM_WARPS = 8  # Triton warps per program (256 threads: 32 elements of a chunk each)


def _interpret() -> bool:
    return jax.default_backend() == "cpu"


def supported(width: int) -> bool:
    """Whether rows of ``width`` can take the kernel here (the GPU lowering's blocks are powers of two)."""
    return _interpret() or (width > 0 and width & (width - 1) == 0)


def _pow2_at_most(n: int) -> int:
    return 1 << (max(n, 1).bit_length() - 1)


def _forward_kernel(h_ref: Any, b_ref: Any, g_ref: Any, o_ref: Any, y_ref: Any, mu_ref: Any, rstd_ref: Any, *,
                    chunk: int, n_chunks: int, eps: float) -> None:
    b, g, o = b_ref[...], g_ref[...], o_ref[...]  # [1, W] float32
    inv_w = 1.0 / h_ref.shape[-1]

    def body(i: Any, carry: Any) -> Any:
        rows = pl.ds(i * chunk, chunk)
        x = h_ref[rows, :].astype(F32) + b
        mu = jnp.sum(x, axis=1, keepdims=True) * inv_w
        centred = x - mu
        rstd = jax.lax.rsqrt(jnp.sum(centred * centred, axis=1, keepdims=True) * inv_w + eps)
        y_ref[rows, :] = jnp.maximum(centred * rstd * g + o, 0.0).astype(y_ref.dtype)
        mu_ref[rows, :] = mu
        rstd_ref[rows, :] = rstd
        return carry

    jax.lax.fori_loop(0, n_chunks, body, 0)


def _kernel(h_ref: Any, dy_ref: Any, mu_ref: Any, rstd_ref: Any, b_ref: Any, g_ref: Any, o_ref: Any,
            dh_ref: Any, db_ref: Any, dg_ref: Any, do_ref: Any, *, chunk: int, n_chunks: int) -> None:
    b, g, o = b_ref[...], g_ref[...], o_ref[...]  # [1, W] float32
    inv_w = 1.0 / h_ref.shape[-1]

    def body(i: Any, sums: tuple) -> tuple:
        rows = pl.ds(i * chunk, chunk)
        rstd = rstd_ref[rows, :]
        xhat = (h_ref[rows, :].astype(F32) + b - mu_ref[rows, :]) * rstd
        dz = jnp.where(xhat * g + o > 0, dy_ref[rows, :].astype(F32), 0.0)
        dxhat = dz * g
        mean_dxhat = jnp.sum(dxhat, axis=1, keepdims=True) * inv_w
        mean_dxhat_xhat = jnp.sum(dxhat * xhat, axis=1, keepdims=True) * inv_w
        dx = rstd * (dxhat - mean_dxhat - xhat * mean_dxhat_xhat)
        dh_ref[rows, :] = dx.astype(dh_ref.dtype)
        sdb, sdg, sdo = sums
        return (sdb + jnp.sum(dx, axis=0, keepdims=True), sdg + jnp.sum(dz * xhat, axis=0, keepdims=True),
                sdo + jnp.sum(dz, axis=0, keepdims=True))

    zeros = jnp.zeros(b.shape, F32)
    sdb, sdg, sdo = jax.lax.fori_loop(0, n_chunks, body, (zeros, zeros, zeros))
    db_ref[...], dg_ref[...], do_ref[...] = sdb, sdg, sdo


def _layout(rows: int, width: int) -> tuple[int, int, int, int]:
    """(rows per block, rows per chunk, blocks, padding rows) for ``rows`` rows of ``width``."""
    block = min(ROWS_PER_BLOCK, 1 << (rows - 1).bit_length())  # a power of two; rows <= block fit one block
    n_blocks = -(-rows // block)
    return block, min(block, _pow2_at_most(CHUNK_ELEMENTS // width)), n_blocks, n_blocks * block - rows


def _triton(interpret: bool) -> Any:
    # Triton, not jax's default GPU lowering (Mosaic GPU, which stages whole blocks in shared memory)
    return None if interpret else pl_triton.CompilerParams(num_warps=NUM_WARPS)


def ln_relu_forward(h: Any, b: Any, g: Any, o: Any, eps: float, interpret: bool | None = None) -> tuple[Any, Any, Any]:
    """``[E, B, W]`` h, ``[E, 1, W]`` b, g, o -> ``y`` ``[E, B, W]`` (h's dtype) and the rows' float32 mean and
    1/std ``[E, B, 1]`` (of ``h + b``, variance + ``eps``). ``interpret`` as in ``ln_relu_backward``."""
    interpret = _interpret() if interpret is None else interpret
    e, rows, width = h.shape
    block, chunk, n_blocks, pad = _layout(rows, width)
    if pad:  # zero rows: finite statistics (rstd = 1/sqrt(eps)), cut off below
        h = jnp.pad(h, ((0, 0), (0, pad), (0, 0)))
    row_block = lambda w: pl.BlockSpec((None, block, w), lambda i, j: (i, j, 0))
    per_member = pl.BlockSpec((None, 1, width), lambda i, j: (i, 0, 0))
    stat = jax.ShapeDtypeStruct((e, n_blocks * block, 1), F32)
    y, mu, rstd = pl.pallas_call(
        functools.partial(_forward_kernel, chunk=chunk, n_chunks=block // chunk, eps=eps),
        out_shape=[jax.ShapeDtypeStruct(h.shape, h.dtype), stat, stat],
        grid=(e, n_blocks),
        in_specs=[row_block(width), per_member, per_member, per_member],
        out_specs=[row_block(width), row_block(1), row_block(1)],
        interpret=interpret,
        compiler_params=_triton(interpret),
        name="ln_relu_forward",
    )(h, b, g, o)
    return (y[:, :rows], mu[:, :rows], rstd[:, :rows]) if pad else (y, mu, rstd)


def ln_relu_backward(h: Any, dy: Any, mu: Any, rstd: Any, b: Any, g: Any, o: Any,
                     interpret: bool | None = None) -> tuple[Any, Any, Any, Any]:
    """``[E, B, W]`` h and dy, ``[E, B, 1]`` mu and rstd, ``[E, 1, W]`` b, g, o -> dh ``[E, B, W]`` and the
    partial sums of db, dg, do, each ``[E, n_blocks, W]`` float32 (sum them over axis 1). ``interpret``: None
    interprets on the CPU backend only (False lowers to Triton, e.g. to lower for a GPU from a CPU machine)."""
    interpret = _interpret() if interpret is None else interpret
    e, rows, width = h.shape
    block, chunk, n_blocks, pad = _layout(rows, width)
    if pad:
        h, dy, mu, rstd = (jnp.pad(a, ((0, 0), (0, pad), (0, 0))) for a in (h, dy, mu, rstd))
    row_block = lambda w: pl.BlockSpec((None, block, w), lambda i, j: (i, j, 0))
    per_member = pl.BlockSpec((None, 1, width), lambda i, j: (i, 0, 0))
    per_block = pl.BlockSpec((None, 1, width), lambda i, j: (i, j, 0))
    partial = jax.ShapeDtypeStruct((e, n_blocks, width), F32)
    dh, db, dg, do = pl.pallas_call(
        functools.partial(_kernel, chunk=chunk, n_chunks=block // chunk),
        out_shape=[jax.ShapeDtypeStruct(h.shape, h.dtype), partial, partial, partial],
        grid=(e, n_blocks),
        in_specs=[row_block(width), row_block(width), row_block(1), row_block(1), per_member, per_member, per_member],
        out_specs=[row_block(width), per_block, per_block, per_block],
        interpret=interpret,
        compiler_params=_triton(interpret),
        name="ln_relu_backward",
    )(h, dy, mu.astype(F32), rstd.astype(F32), b, g, o)
    return (dh[:, :rows] if pad else dh), db, dg, do
