"""Running statistics: Chan merge equals the statistics of the concatenated data."""

from __future__ import annotations

import numpy as np
from core_helpers import assert_close, f32, to_np

from unilab_jax.core.normalizer import RunningStats, normalize, stats_init, stats_merge, stats_update

D = 5


def _data(seed: int, n: int, shift: float):
    rng = np.random.default_rng(seed)
    return f32(rng.normal(size=(n, D)) * rng.uniform(0.5, 3.0, size=D) + shift)


def test_updates_and_merge_equal_concatenated_statistics(backend):
    a1, a2, b1 = _data(0, 300, 1.0), _data(1, 57, -2.0), _data(2, 1000, 5.0)
    put = backend.from_numpy
    worker_a = stats_update(stats_update(stats_init(D, backend), put(a1)), put(a2))
    worker_b = stats_update(stats_init(D, backend), put(b1))
    merged = stats_merge(worker_a, worker_b)
    everything = np.concatenate([a1, a2, b1]).astype(np.float64)
    assert_close(merged.mean, everything.mean(0), rtol=1e-5, atol=1e-5)
    assert_close(merged.var, everything.var(0), rtol=1e-5, atol=1e-5)
    assert float(to_np(merged.count)) == len(everything)
    assert_close(worker_a.var, np.concatenate([a1, a2]).astype(np.float64).var(0), rtol=1e-5)
    for leaf in merged:
        assert leaf.dtype == backend.float32


def test_merge_hand_computed_and_empty():
    a = RunningStats(f32([0.0]), f32([1.0]), np.float32(2.0))  # data {-1, 1}
    b = RunningStats(f32([3.0]), f32([0.0]), np.float32(1.0))  # data {3}
    m = stats_merge(a, b)
    np.testing.assert_allclose(m.mean, [1.0], rtol=1e-6)
    np.testing.assert_allclose(m.var, [np.var([-1.0, 1.0, 3.0])], rtol=1e-6)
    empty = stats_init(1, __import__("unilab_jax.xp", fromlist=["get"]).get("numpy"))
    for x, y in ((empty, b), (b, empty)):
        m = stats_merge(x, y)
        np.testing.assert_allclose(m.mean, b.mean)
        np.testing.assert_allclose(m.var, b.var)
        assert float(m.count) == 1.0
    m = stats_merge(empty, empty)
    np.testing.assert_allclose(m.var, [1.0])
    assert float(m.count) == 0.0


def test_update_flattens_leading_axes_and_normalize(backend):
    x = _data(3, 64, 0.5)
    stats = stats_update(stats_init(D, backend), backend.from_numpy(x.reshape(8, 8, D)))
    assert_close(stats.mean, x.astype(np.float64).mean(0))
    y = normalize(stats, backend.from_numpy(x))
    expected = (x - x.mean(0)) / np.sqrt(x.var(0) + 1e-8)
    assert_close(y, expected, rtol=1e-4, atol=1e-4)
    far = backend.from_numpy(f32(np.full((2, D), 1e6)))
    assert_close(normalize(stats, far), np.full((2, D), 10.0))
    assert_close(normalize(stats, far, clip=3.0), np.full((2, D), 3.0))
    assert float(to_np(normalize(stats, far, clip=None))[0, 0]) > 1e4
    identity = normalize(stats_init(D, backend), backend.from_numpy(x))
    assert_close(identity, x, rtol=1e-6, atol=1e-6)
