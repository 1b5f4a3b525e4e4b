"""Running mean/variance statistics (observation / reward normalisation), mergeable across workers.

``RunningStats(mean [D], var [D], count [])``: ``var`` is the population variance of everything seen
so far and ``count`` the number of rows (float32; once it is huge the statistics effectively freeze,
as any running average does). Updates use Chan et al.'s parallel merge, so merging the statistics of
two workers equals the statistics of their concatenated data.
"""

from __future__ import annotations

from typing import Any, NamedTuple

from unilab_jax import xp as shim


class RunningStats(NamedTuple):
    """Statistics of the rows seen so far: ``mean [D]``, population ``var [D]``, ``count []``."""

    mean: Any  # [D]
    var: Any  # [D] population variance
    count: Any  # [] number of rows seen


def stats_init(dim: int, xp: shim.Backend) -> RunningStats:
    """Empty statistics for D = ``dim`` features on backend ``xp``: mean 0, var 1 (``normalize`` is the
    identity until data arrives), count 0."""
    return RunningStats(
        mean=xp.zeros((dim,), dtype=xp.float32),
        var=xp.ones((dim,), dtype=xp.float32),
        count=xp.zeros((), dtype=xp.float32),
    )


def stats_merge(a: RunningStats, b: RunningStats) -> RunningStats:
    """Exact merge of two sets of statistics (e.g. from two workers); either may be empty (count 0).

    mean/var: [D]; count: []. Returns RunningStats over the union of both data sets.
    """
    xp = shim.namespace(a.mean, a.var, a.count, b.mean, b.var, b.count)
    n = a.count + b.count
    safe_n = xp.where(n > 0, n, xp.ones_like(n))
    wb = b.count / safe_n
    delta = b.mean - a.mean
    mean = a.mean + delta * wb
    var = (a.var * a.count + b.var * b.count) / safe_n + xp.square(delta) * ((a.count / safe_n) * wb)
    empty = n <= 0
    return RunningStats(mean=xp.where(empty, a.mean, mean), var=xp.where(empty, a.var, var), count=n)


def stats_update(stats: RunningStats, batch: Any) -> RunningStats:
    """Adds a batch of rows. batch: [N, D] (or [..., D], flattened). Returns the updated statistics."""
    xp = shim.namespace(stats.mean, batch)
    d = int(batch.shape[-1])
    rows = xp.reshape(batch, (-1, d))
    n = int(rows.shape[0])
    if n == 0:
        return stats
    mean = xp.mean(rows, axis=0)
    var = xp.mean(xp.square(rows - mean), axis=0)
    return stats_merge(stats, RunningStats(mean=mean, var=var, count=xp.asarray(float(n), dtype=xp.float32)))


def normalize(stats: RunningStats, x: Any, clip: float | None = 10.0, eps: float = 1e-8) -> Any:
    """``clip((x - mean) / sqrt(var + eps), -clip, clip)``; x: [..., D]. Returns [..., D]; ``clip=None``
    disables clipping."""
    xp = shim.namespace(stats.mean, x)
    y = (x - stats.mean) / xp.sqrt(stats.var + eps)
    return y if clip is None else xp.clip(y, -clip, clip)
