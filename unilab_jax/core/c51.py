"""Categorical (C51) distributional critic: target projection, cross-entropy loss, mean value.

``atoms`` is the fixed support [K] (increasing; usually ``linspace(v_min, v_max, K)``); ``logits``
and ``probs`` are [B, K]. Two projections give the same result: ``categorical_projection`` for any
increasing support (memory and work B K^2), ``categorical_projection_uniform`` for the support
``linspace(v_min, v_max, K)`` (memory and work B K; FastSAC's and FlashSAC's ``projection="prefix"``).
"""

from __future__ import annotations

from typing import Any

from unilab_jax import xp as shim


def uniform_support(v_min: float, v_max: float, k: int, xp: Any, dtype: Any = None) -> Any:
    """The support ``linspace(v_min, v_max, k)`` [k] (float32 unless ``dtype``) as a constant.

    Each atom is rounded once from its float64 value, so the atoms are the same on every backend, eagerly
    and under jit (``xp.linspace`` under ``jax.jit`` differs from eager jax in the last bit of some atoms).
    """
    step = (v_max - v_min) / (k - 1)
    return xp.asarray([v_min + i * step for i in range(k - 1)] + [v_max], dtype=xp.float32 if dtype is None else dtype)


def categorical_projection(atoms: Any, next_probs: Any, rewards: Any, discounts: Any) -> Any:
    """Projects the distribution of ``r + discounts * Z'`` back onto ``atoms`` (Cramer/L2 projection).

    Args:
      atoms: [K] support, increasing. next_probs: [B, K] probabilities of Z' on ``atoms``.
      rewards, discounts: [B] (discounts = gamma^n (1 - terminated)).

    Returns:
      [B, K] projected target probabilities (gradient-stopped), identical to
      ``rlax.categorical_l2_project(r + d * atoms, next_probs, atoms)`` per row: the shifted atoms
      are clipped to [atoms[0], atoms[-1]] and each one's mass is split between its two neighbouring
      atoms in proportion to distance. Written scatter-free as a dense [B, K, K] triangular-kernel
      weight, ``out[b, i] = sum_j clip(1 - |z[b, j] - atoms[i]| / spacing, 0, 1) p[b, j]`` (memory
      B * K^2; under jit the weight fuses into the reduction).

    The inputs are materialised first: otherwise XLA (GPU) fuses their producers, e.g. the softmax
    of the target critic with its per-row sum, into the [B, K, K] reduction and recomputes them for
    each of the K^2 weights (measured on an H100, B 8192, K 101: 6.0 ms instead of 0.27 ms;
    bench/c51_projection.py).
    """
    xp = shim.namespace(atoms, next_probs, rewards, discounts)
    next_probs, rewards, discounts = xp.materialize((next_probs, rewards, discounts))
    k = int(atoms.shape[0])
    z = rewards[:, None] + discounts[:, None] * atoms[None, :]  # [B, K]
    z = xp.clip(z, atoms[0], atoms[k - 1])
    gaps = atoms[1:] - atoms[:-1]  # [K-1]
    inv = xp.where(gaps > 0, 1.0 / xp.where(gaps > 0, gaps, xp.ones_like(gaps)), xp.zeros_like(gaps))
    zero = xp.zeros((1,), dtype=inv.dtype)
    inv_pos = xp.concat([inv, zero])  # 1 / (atoms[i+1] - atoms[i]); 0 for the last atom
    inv_neg = xp.concat([zero, inv])  # 1 / (atoms[i] - atoms[i-1]); 0 for the first atom
    delta = z[:, None, :] - atoms[None, :, None]  # [B, K(target i), K(source j)]
    scale = xp.where(delta >= 0, inv_pos[None, :, None], -inv_neg[None, :, None])
    weight = xp.clip(1.0 - delta * scale, 0.0, 1.0)
    out = xp.sum(weight * next_probs[:, None, :], axis=-1)
    return xp.stop_gradient(out)


def categorical_projection_uniform(next_probs: Any, rewards: Any, discounts: Any, *, v_min: float,
                                   v_max: float) -> Any:
    """``categorical_projection`` onto the uniform support ``linspace(v_min, v_max, K)``, in O(B K) memory and work.

    Args:
      next_probs: [B, K] probabilities of Z' on ``uniform_support(v_min, v_max, K)`` (K >= 2, from the shape).
      rewards, discounts: [B]; discounts >= 0 (``gamma^n (1 - terminated)``).
      v_min, v_max: python floats, v_min < v_max.

    Returns:
      [B, K] projected target probabilities (gradient-stopped): ``categorical_projection(atoms, ...)`` with
      ``atoms = uniform_support(v_min, v_max, K, xp, next_probs.dtype)``, up to float32 rounding.

    The shifted atoms ``z[b, j] = clip(r_b + d_b atoms[j])`` are non-decreasing in j, so the sources in the
    cell [atoms[c], atoms[c+1]] of a row are a contiguous range of j, and the row's affine map gives its
    ends: ``ceil((atoms[c] - r_b - d_b atoms[0]) / (d_b dz))`` sources lie below atoms[c]. A source in cell
    c at fraction tau of it gives ``1 - tau`` of its mass to atom c and ``tau`` to atom c+1, so each atom
    receives sums of p (1 - tau) and p tau over the ranges of two cells: differences of prefix sums
    (``cumulative_sum``) gathered at the ends (``take_along_axis``). Memory and work are O(B K) instead of
    the dense form's B K^2, without a scatter; the dense form was the costliest single kernel of the
    FastSAC update (124 us per gradient step on an H100, B 8192, K 101; bench/c51_projection.py times both).

    The ends are rounded: a source within a few float32 ulps of an atom may be counted in the cell next to
    its own, where its fraction falls just outside [0, 1]. It then gives ``max(-tau, 0)`` to atom c-1 and
    ``max(tau - 1, 0)`` to atom c+2 as well (with atoms c and c+1 corrected to match), which is where the
    hat functions of ``categorical_projection`` put its mass. Each source's cell is the number of ends at or
    below its index, counted near ``floor((z - v_min) / dz)``, so cells and ranges agree exactly.
    """
    xp = shim.namespace(next_probs, rewards, discounts)
    b, k = (int(n) for n in next_probs.shape)
    atoms = uniform_support(v_min, v_max, k, xp, next_probs.dtype)
    dz = (v_max - v_min) / (k - 1)
    # Under jit the ends are computed from these [B] vectors in more than one fused kernel; computing the
    # vectors once keeps the rounding of the ends the same in all of them.
    start, step = xp.materialize((rewards + discounts * atoms[0], discounts * dz))
    z = xp.clip(rewards[:, None] + discounts[:, None] * atoms[None, :], atoms[0], atoms[k - 1])  # [B, K]

    # ends[:, c + 2]: how many sources lie below atoms[c] by the row's affine map, for c = -2 .. K+1 (0 up to
    # c = 0, K from c = K-1): [B, K+4]. The range of cell c is ends[:, c + 2] <= j < ends[:, c + 3].
    inner = atoms[None, 1:k - 1] - start[:, None]  # [B, K-2]
    moving = step[:, None] > 0
    still = float(k) * xp.astype(inner > 0, inner.dtype)  # discount 0: every source sits at clip(r)
    inner = xp.where(moving, xp.ceil(inner / xp.where(moving, step[:, None], 1.0)), still)
    ends = xp.concat([xp.zeros((b, 3), dtype=xp.int32), xp.astype(xp.clip(inner, 0.0, float(k)), xp.int32),
                      xp.full((b, 3), k, dtype=xp.int32)], axis=-1)

    # The cell of source j: #{c in 1 .. K-2: ends[:, c + 2] <= j}, at most one off floor((z - v_min) / dz).
    base = xp.astype(xp.clip(xp.floor((z - atoms[0]) * (1.0 / dz)) - 1.0, 0.0, float(k - 2)), xp.int32)
    checks = xp.take_along_axis(ends[None, ...], xp.stack([base + 3, base + 4]), axis=-1)  # [2, B, K]
    cell = base + xp.sum(xp.astype(checks <= xp.arange(k, dtype=xp.int32), xp.int32), axis=0)
    sides = xp.take_along_axis(atoms[None, None, :], xp.stack([cell, cell + 1]), axis=-1)  # atoms c, c+1
    tau = (z - sides[0, ...]) / (sides[1, ...] - sides[0, ...])

    # Weights of a source to atoms c-1 .. c+2 of its cell c, times p, summed per cell by prefix sums.
    below, above = xp.maximum(-tau, 0.0), xp.maximum(tau - 1.0, 0.0)
    weights = xp.stack([below, 1.0 - tau - 2.0 * below + above, tau + below - 2.0 * above, above])
    prefix = xp.cumulative_sum(weights * next_probs, axis=-1, include_initial=True)  # [4, B, K+1]
    at_ends = xp.take_along_axis(prefix, ends[None, ...], axis=-1)  # [4, B, K+4]
    cells = at_ends[..., 1:] - at_ends[..., :k + 3]  # [4, B, K+3]: row o summed over cell c at c + 2
    # Atom i receives row o (atom offset o - 1) of cell i + 1 - o.
    out = cells[0, :, 3:k + 3] + cells[1, :, 2:k + 2] + cells[2, :, 1:k + 1] + cells[3, :, :k]
    return xp.stop_gradient(out)


def categorical_critic_loss(logits: Any, target_probs: Any) -> Any:
    """Cross-entropy ``mean_b(-sum_k target[b, k] log softmax(logits)[b, k])``.

    logits: [B, K]; target_probs: [B, K] (gradient stopped). Returns a scalar.
    """
    xp = shim.namespace(logits, target_probs)
    return xp.mean(-xp.sum(xp.stop_gradient(target_probs) * xp.log_softmax(logits, axis=-1), axis=-1))


def categorical_mean(logits: Any, atoms: Any) -> Any:
    """Expected value ``sum_k softmax(logits)[b, k] atoms[k]``. logits: [B, K]; atoms: [K]. Returns [B]."""
    xp = shim.namespace(logits, atoms)
    return xp.sum(xp.softmax(logits, axis=-1) * atoms, axis=-1)
