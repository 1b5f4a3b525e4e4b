"""RLPD kernels (unilab_jax.core.rlpd_kernels) on hand-computed cases, on numpy, jax and mlx."""

from __future__ import annotations

import numpy as np
import pytest

from unilab_jax import xp as shim
from unilab_jax.core import rlpd_kernels as rlpd

BACKENDS = ["numpy", "jax", "mlx"]


def _xp(name):
    pytest.importorskip("mlx.core" if name == "mlx" else name)
    return shim.get(name)


@pytest.mark.parametrize("backend", BACKENDS)
def test_subset_min_hand_computed(backend):
    xp = _xp(backend)
    # 4 members, 3 samples; noise picks members 2 and 0 (the two smallest u)
    u = xp.asarray(np.array([0.30, 0.91, 0.05, 0.47], np.float32))
    np.testing.assert_array_equal(np.asarray(rlpd.subset_indices(u, 2)), [2, 0])
    # an ensemble of 4 one-weight "critics" whose values are their weight times x: [E, B]
    ensemble = {"w": xp.asarray(np.array([[[1.0]], [[0.0]], [[3.0]], [[-7.0]]], np.float32))}
    x = xp.asarray(np.array([[1.0, 2.0, -1.0]], np.float32))  # [1, B]

    def subset_min(k):
        sub = rlpd.ensemble_members(ensemble, rlpd.subset_indices(u, k))
        return np.asarray(xp.min(sub["w"][:, 0, :] * x, axis=0))  # [k, 1] x [1, B] -> min over k: [B]

    # members 2, 0: q rows [3, 6, -3] and [1, 2, -1]; member 3 (-7 x) would be the smallest where x > 0
    np.testing.assert_allclose(subset_min(2), [1.0, 2.0, -3.0])
    np.testing.assert_allclose(subset_min(1), [3.0, 6.0, -3.0])  # member 2 alone
    np.testing.assert_allclose(subset_min(4), [-7.0, -14.0, -3.0])  # k = E: the plain min over the ensemble


def test_subset_is_uniform_over_pairs():
    rng = np.random.default_rng(0)
    counts = np.zeros(10)
    for _ in range(2000):
        members = rlpd.subset_indices(rng.random(10).astype(np.float32), 2)
        assert len(set(members.tolist())) == 2
        counts[members] += 1
    # each member in 2/10 of the subsets: 400 of 2000 (binomial std ~18)
    assert np.all(np.abs(counts - 400) < 80), counts


@pytest.mark.parametrize("backend", BACKENDS)
def test_ensemble_critic_loss_hand_computed(backend):
    xp = _xp(backend)
    q = xp.asarray(np.array([[1.0, 2.0], [3.0, 0.0], [0.0, 2.0]], np.float32))
    y = xp.asarray(np.array([1.0, 1.0], np.float32))
    # squared errors: [0, 1], [4, 1], [1, 1] -> sum 8 over 6 entries
    assert float(rlpd.ensemble_critic_loss(q, y)) == pytest.approx(8.0 / 6.0)


def test_symmetric_batch_composition():
    assert rlpd.symmetric_split(256) == (128, 128)
    assert rlpd.symmetric_split(5, 0.5) == (3, 2)  # round half to even: 2 prior rows
    assert rlpd.symmetric_split(10, 0.0) == (10, 0) and rlpd.symmetric_split(10, 1.0) == (0, 10)
    with pytest.raises(ValueError, match="prior_fraction"):
        rlpd.symmetric_split(10, 1.5)
    online = {"reward": np.array([[1.0, 2.0], [3.0, 4.0]], np.float32),
              "obs": np.arange(8, dtype=np.float32).reshape(2, 2, 2)}
    prior = {"reward": np.array([[10.0], [30.0]], np.float32), "obs": -np.ones((2, 1, 2), np.float32),
             "episode": np.zeros((2, 1), np.int32)}
    out = rlpd.compose(online, prior)
    assert set(out) == {"reward", "obs"}  # the online fields
    np.testing.assert_array_equal(out["reward"], [[1.0, 2.0, 10.0], [3.0, 4.0, 30.0]])
    np.testing.assert_array_equal(out["obs"][1], [[4.0, 5.0], [6.0, 7.0], [-1.0, -1.0]])
