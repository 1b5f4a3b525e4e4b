"""C51 projection against rlax.categorical_l2_project; loss and mean by hand."""

from __future__ import annotations

import numpy as np
import pytest
from core_helpers import assert_close, f32

from unilab_jax import xp as shim
from unilab_jax.core.c51 import categorical_critic_loss, categorical_mean, categorical_projection

jax = pytest.importorskip("jax")
jnp = jax.numpy
rlax = pytest.importorskip("rlax")


def _inputs(seed: int, b: int = 32, k: int = 101, v: float = 10.0):
    rng = np.random.default_rng(seed)
    atoms = np.linspace(-v, v, k)
    probs = rng.dirichlet(np.ones(k) * 0.3, size=b)
    rewards = rng.normal(size=b) * 4.0  # some targets fall outside [-v, v] and get clipped
    discounts = np.where(rng.random(b) < 0.2, 0.0, 0.99)
    return f32(atoms, probs, rewards, discounts)


def _rlax(atoms, probs, rewards, discounts):
    f = lambda p, r, d: rlax.categorical_l2_project(r + d * jnp.asarray(atoms), p, jnp.asarray(atoms))
    return jax.jit(jax.vmap(f))(jnp.asarray(probs), jnp.asarray(rewards), jnp.asarray(discounts))


@pytest.mark.parametrize("k", [101, 51, 5])
def test_projection_matches_rlax(k):
    atoms, probs, rewards, discounts = _inputs(k, k=k)
    jx = shim.get("jax")
    got = categorical_projection(*(jx.from_numpy(a) for a in (atoms, probs, rewards, discounts)))
    assert got.shape == probs.shape and got.dtype == jnp.float32
    assert_close(got, _rlax(atoms, probs, rewards, discounts), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(got).sum(-1), 1.0, rtol=1e-5)


def test_projection_non_uniform_support_matches_rlax():
    atoms = f32(np.sort(np.concatenate([[-5.0, 5.0], np.random.default_rng(0).uniform(-5, 5, 19)])))
    _, probs, rewards, discounts = _inputs(1, b=16, k=21)
    got = categorical_projection(atoms, probs, rewards * 0.5, discounts)
    assert_close(got, _rlax(atoms, probs, rewards * 0.5, discounts), rtol=1e-5, atol=1e-6)


def test_projection_hand_computed():
    atoms = f32([0.0, 1.0, 2.0])
    probs = f32([[0.2, 0.3, 0.5], [1.0, 0.0, 0.0]])
    # row 0: z = .5 + .5*atoms = .5, 1, 1.5 -> .2 split .1/.1 on atoms 0/1, .3 on 1, .5 split .25/.25 on 1/2
    # row 1: z = 5 + 0*atoms = 5 -> clipped to 2
    got = categorical_projection(atoms, probs, f32([0.5, 5.0]), f32([0.5, 0.0]))
    np.testing.assert_allclose(got, [[0.1, 0.65, 0.25], [0.0, 0.0, 1.0]], rtol=1e-6, atol=1e-7)


def test_loss_and_mean_hand_computed(backend):
    logits = backend.from_numpy(f32(np.log([[0.25, 0.25, 0.5], [0.1, 0.6, 0.3]])))
    target = backend.from_numpy(f32([[0.0, 1.0, 0.0], [0.5, 0.0, 0.5]]))
    atoms = backend.from_numpy(f32([-1.0, 0.0, 1.0]))
    expected = (-np.log(0.25) + -(0.5 * np.log(0.1) + 0.5 * np.log(0.3))) / 2
    assert_close(categorical_critic_loss(logits, target), expected, rtol=1e-6)
    assert_close(categorical_mean(logits, atoms), [0.25, 0.2], rtol=1e-6, atol=1e-7)
