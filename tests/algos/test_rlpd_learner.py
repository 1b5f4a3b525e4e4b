"""RLPD's learner: the ensemble's shapes, the delayed actor (``actor_every``) and the registry."""

from __future__ import annotations

import numpy as np
import pytest

from tasks.base import TaskSpec
from unilab_jax import algos
from unilab_jax.algos.offpolicy import rlpd

SPEC = TaskSpec(name="t", obs_dim=5, critic_obs_dim=7, action_dim=2, episode_length=50, ctrl_dt=0.02,
                reward_terms=("r",))
U, B = 3, 16


def _batch(seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    f = lambda *s: rng.normal(size=s).astype(np.float32)  # noqa: E731
    return {"obs": f(U, B, 5), "critic_obs": f(U, B, 7), "next_obs": f(U, B, 5), "next_critic_obs": f(U, B, 7),
            "action": np.tanh(f(U, B, 2)), "reward": f(U, B), "terminated": rng.random((U, B)) < 0.1,
            "truncated": np.zeros((U, B), bool)}


def test_delayed_actor_and_ensemble():
    jax = pytest.importorskip("jax")
    config = rlpd.Config(actor_hidden=(16,), critic_hidden=(16,), batch_size=B, updates_per_call=U, num_critics=5,
                         actor_every=U + 1)
    learner = algos.make_learner("rlpd", "jax", config, SPEC)
    state = learner.init(jax.random.PRNGKey(0))
    assert state.critic[0]["w"].shape == (5, 7 + 2, 16) and "g" in state.critic[0]  # 5 members, LayerNorm
    first, metrics = learner.update(state, _batch(0))  # steps 1..U: none is the (U+1)-th
    assert float(metrics["actor_steps"]) == 0.0 and float(metrics["actor_loss"]) == 0.0
    np.testing.assert_array_equal(np.asarray(first.actor[0]["w"]), np.asarray(state.actor[0]["w"]))
    assert float(first.log_alpha) == float(state.log_alpha)
    assert not np.array_equal(np.asarray(first.critic[0]["w"]), np.asarray(state.critic[0]["w"]))
    second, metrics = learner.update(first, _batch(1))  # step U+1 moves the actor once
    assert float(metrics["actor_steps"]) == 1.0 and float(metrics["actor_loss"]) != 0.0
    assert not np.array_equal(np.asarray(second.actor[0]["w"]), np.asarray(first.actor[0]["w"]))
    assert int(second.steps) == 2 * U


def test_config_checks_and_registry():
    assert "rlpd" in algos.names()
    with pytest.raises(ValueError, match="subset_size"):
        rlpd.Config(num_critics=2, subset_size=3)
    with pytest.raises(ValueError, match="actor_every"):
        rlpd.Config(actor_every=0)
    with pytest.raises(ValueError, match="prior_fraction"):
        rlpd.Config(prior_fraction=1.0)
