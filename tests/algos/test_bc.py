"""Behaviour cloning (``algos/imitation``): the loss by hand, the fit drives it down on a learnable mapping."""

from __future__ import annotations

import numpy as np
import pytest

from unilab_jax import xp as shim
from unilab_jax.algos.imitation import bc
from unilab_jax.core import normalizer

NP = shim.get("numpy")


def test_loss_by_hand():
    # One linear layer (no hidden): policy = tanh(x' w + b), x' = x / sqrt(1 + VAR_FLOOR) (mean 0, var 1 stats).
    actor = [{"w": np.array([[1.0, 0.0], [0.0, 2.0]], np.float32), "b": np.array([0.0, 0.5], np.float32)}]
    stats = normalizer.stats_init(2, NP)
    obs = np.array([[0.5, -0.25]], np.float32)
    target = np.array([[0.0, 1.0]], np.float32)
    s = 1.0 / np.sqrt(1.0 + bc.VAR_FLOOR)
    pred = np.tanh([0.5 * s, 2.0 * -0.25 * s + 0.5])
    want = (pred[0] - 0.0) ** 2 + (pred[1] - 1.0) ** 2
    assert float(bc.loss(actor, stats, obs, target)) == pytest.approx(want, rel=1e-5)
    action, extras = bc.act({"actor": actor, "obs_norm": stats}, obs, None)
    assert extras == {} and action.dtype == np.float32
    np.testing.assert_allclose(action[0], pred, atol=1e-6)


def test_fit_learns_a_mapping_and_checks_inputs():
    pytest.importorskip("jax")
    from unilab_jax.algos.imitation import learner_jax

    rng = np.random.default_rng(0)
    obs = rng.normal(size=(512, 4)).astype(np.float32)
    action = np.tanh(obs[:, :2] @ np.array([[0.8, -0.5], [0.3, 0.9]], np.float32))
    config = bc.BCConfig(hidden=(32,), epochs=200, weight_decay=0.0)
    weights, metrics = learner_jax.fit(obs, action, config, seed=1)
    untrained, _ = learner_jax.fit(obs, action, bc.BCConfig(hidden=(32,), epochs=1, weight_decay=0.0), seed=1)
    err = float(np.mean((bc.act(weights, obs, None)[0] - action) ** 2))
    err0 = float(np.mean((bc.act(untrained, obs, None)[0] - action) ** 2))
    assert metrics["rows"] == 512 and err < 0.02 and err < err0 / 10, (err, err0)
    with pytest.raises(ValueError, match="obs"):
        learner_jax.fit(obs[:0], action[:0], config)
    with pytest.raises(ValueError, match="weight_decay"):
        bc.BCConfig(weight_decay=-1.0)
