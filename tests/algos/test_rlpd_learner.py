"""RLPD's learner (and RLPD Flow's, its flow actor): the ensemble's shapes, the delayed actor (``actor_every``)
and the registry."""

from __future__ import annotations

import numpy as np
import pytest
from compile_options import FAST_COMPILE

from tasks.base import TaskSpec
from unilab_jax import algos, nets
from unilab_jax.algos import contract
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


# name -> (the learner's normals per sample, its entropy target at |A| = 2, the published actor's kind)
ACTORS = {"rlpd": (2, -1.0, list), "rlpd_flow": ((4 + 1) * 2, 0.0, dict)}  # tanh-Gaussian; SAC Flow's K = 4 chain


@pytest.mark.parametrize("name", sorted(ACTORS))
def test_delayed_actor_and_ensemble(name):
    jax = pytest.importorskip("jax")
    leaves = lambda tree: [np.asarray(x) for x in jax.tree_util.tree_leaves(tree)]  # noqa: E731
    moved = lambda a, b: any(not np.array_equal(x, y) for x, y in zip(leaves(a), leaves(b)))  # noqa: E731
    decl = algos.get(name)
    config = decl.Config(actor_hidden=(16,), critic_hidden=(16,), batch_size=B, updates_per_call=U, num_critics=5,
                         actor_every=U + 1)
    from unilab_jax.algos.offpolicy import learner_jax

    assert type(algos.make_learner(name, "jax", config, SPEC)) is learner_jax.SACFamilyLearner
    # The registry's learner, compiled with XLA's fast-compile options (tests/compile_options.py: ~14 -> ~5 CPU-s)
    learner = learner_jax.SACFamilyLearner(decl, config, SPEC, compiler_options=FAST_COMPILE)
    noise_dim, target_entropy, actor_kind = ACTORS[name]
    assert (learner.noise_dim, learner.critic_noise_shape, learner.target_entropy) == (noise_dim, (5,), target_entropy)
    state = learner.init(jax.random.PRNGKey(0))
    assert state.critic[0]["w"].shape == (5, 7 + 2, 16) and "g" in state.critic[0]  # 5 members, LayerNorm
    first, metrics = learner.update(state, _batch(0))  # steps 1..U: none is the (U+1)-th
    assert float(metrics["actor_steps"]) == 0.0 and float(metrics["actor_loss"]) == 0.0
    assert not moved(first.actor, state.actor) and float(first.log_alpha) == float(state.log_alpha)
    assert moved(first.critic, state.critic)
    second, metrics = learner.update(first, _batch(1))  # step U+1 moves the actor once
    assert float(metrics["actor_steps"]) == 1.0 and float(metrics["actor_loss"]) != 0.0
    assert moved(second.actor, first.actor) and float(second.log_alpha) != float(first.log_alpha)
    assert int(second.steps) == 2 * U
    assert all(np.isfinite(float(v)) for v in metrics.values()), metrics
    # What the workers get: weights of the declaration's actor (RLPD Flow: SAC Flow's), which its act runs on.
    weights = nets.to_numpy(learner.weights(second))
    assert isinstance(weights["actor"], actor_kind)
    obs = np.random.default_rng(3).normal(size=(4, 5)).astype(np.float32)
    noise = np.random.default_rng(4).normal(size=(4, contract.hooks(decl).noise_dim(2))).astype(np.float32)
    action, _ = decl.act(weights, obs, noise, False)
    assert action.shape == (4, 2) and np.all(np.abs(action) < 1.0)
    assert not np.allclose(action, decl.act(weights, obs, noise, True)[0])


def test_config_checks_and_registry():
    assert "rlpd" in algos.names()
    with pytest.raises(ValueError, match="subset_size"):
        rlpd.Config(num_critics=2, subset_size=3)
    with pytest.raises(ValueError, match="actor_every"):
        rlpd.Config(actor_every=0)
    with pytest.raises(ValueError, match="prior_fraction"):
        rlpd.Config(prior_fraction=1.0)
