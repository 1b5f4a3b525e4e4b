"""C51 projections (dense and uniform-support) against rlax.categorical_l2_project; loss and mean by hand."""

from __future__ import annotations

import numpy as np
import pytest
from core_helpers import assert_close, f32

from unilab_jax import xp as shim
from unilab_jax.core.c51 import (
    categorical_critic_loss,
    categorical_mean,
    categorical_projection,
    categorical_projection_uniform,
    uniform_support,
)

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


def _uniform_inputs(k: int, v_min: float, v_max: float):
    """Rows that stress the uniform projection: random rows (targets inside and beyond the support); rows whose
    heaviest source (half the mass) lands on an atom, a float32 ulp either side of one, or between two, under
    discounts 0, 1e-6, 0.5, 0.99 and 1; one-hot rows at both edges."""
    rng = np.random.default_rng(k)
    atoms = np.asarray(uniform_support(v_min, v_max, k, shim.get("numpy")))
    some = atoms[::max(1, k // 25)]  # every atom of a small support, every 4th of 101: the dense reference stays cheap
    marks = np.concatenate([some, np.nextafter(some, np.inf), np.nextafter(some, -np.inf),
                            some[1:] - np.diff(some) / 2])
    d_marks = np.repeat(f32([0.0, 1e-6, 0.5, 0.99, 1.0]), marks.size)
    heavy = rng.integers(k, size=d_marks.size)
    r_marks = np.tile(marks, 5) - d_marks * atoms[heavy]
    n_random = 64
    rewards = np.concatenate([r_marks, rng.normal(size=n_random) * (v_max - v_min)])
    discounts = np.concatenate([d_marks, rng.choice(f32([0.0, 1e-6, 0.99]), n_random)])
    probs = rng.dirichlet(np.ones(k) * 0.3, size=rewards.size)
    probs[:heavy.size] = 0.5 * probs[:heavy.size] + 0.5 * np.eye(k)[heavy]
    probs[-4:] = np.eye(k)[[0, 0, k - 1, k - 1]]  # one-hot at the edges
    return f32(atoms, probs, rewards, discounts)


@pytest.mark.parametrize("k, v_min, v_max", [(101, -10.0, 10.0), (101, -0.5, 1.5), (51, -3.0, 4.0), (5, -1.0, 1.0),
                                             (2, 0.0, 1.0)])
def test_uniform_projection_matches_rlax_and_dense(k, v_min, v_max):
    # Under jax.jit as FastSAC runs it: rlax and the dense form round z = r + d atoms as the same compiler does.
    atoms, probs, rewards, discounts = _uniform_inputs(k, v_min, v_max)
    got = jax.jit(lambda p, r, d: categorical_projection_uniform(p, r, d, v_min=v_min, v_max=v_max))(
        probs, rewards, discounts)
    assert got.shape == probs.shape and got.dtype == jnp.float32
    assert_close(got, _rlax(atoms, probs, rewards, discounts), rtol=1e-5, atol=1e-6)
    assert_close(got, jax.jit(categorical_projection)(atoms, probs, rewards, discounts), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(got).sum(-1), 1.0, rtol=1e-5)


@pytest.mark.parametrize("k, v_min, v_max", [(101, -0.5, 1.5), (5, -1.0, 1.0)])
def test_uniform_projection_matches_dense_on_every_backend(backend, k, v_min, v_max):
    # Compiled on each backend (identity on numpy), against the dense form compiled there (same rounding of z).
    arrays = _uniform_inputs(k, v_min, v_max)
    atoms, probs, rewards, discounts = (backend.from_numpy(a) for a in arrays)
    got = backend.jit(lambda p, r, d: categorical_projection_uniform(p, r, d, v_min=v_min, v_max=v_max))(
        probs, rewards, discounts)
    assert_close(got, backend.jit(categorical_projection)(atoms, probs, rewards, discounts), rtol=1e-5, atol=1e-6)


def test_uniform_projection_hand_computed():
    probs = f32([[0.2, 0.3, 0.5], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    # as test_projection_hand_computed; row 2: z = -1 + 0.25 * 2 = -0.5 -> clipped to 0
    got = categorical_projection_uniform(probs, f32([0.5, 5.0, -1.0]), f32([0.5, 0.0, 0.25]), v_min=0.0, v_max=2.0)
    np.testing.assert_allclose(got, [[0.1, 0.65, 0.25], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], rtol=1e-6, atol=1e-7)


def test_projections_stop_gradients():
    atoms, probs, rewards, discounts = (jnp.asarray(a) for a in _inputs(0, b=4, k=11))

    def objective(p, r, d):
        weights = jnp.arange(11.0)
        return jnp.sum((categorical_projection(atoms, p, r, d)
                        + categorical_projection_uniform(p, r, d, v_min=-10.0, v_max=10.0)) * weights)

    for g in jax.jit(jax.grad(objective, argnums=(0, 1, 2)))(probs, rewards, discounts):
        np.testing.assert_array_equal(g, 0.0)


def test_uniform_support_is_the_same_everywhere(backend):
    want = np.asarray(uniform_support(-0.5, 1.5, 101, shim.get("numpy")))
    assert want.dtype == np.float32 and want[0] == -0.5 and want[-1] == 1.5
    np.testing.assert_allclose(want, np.linspace(-0.5, 1.5, 101), rtol=0, atol=1e-7)
    np.testing.assert_array_equal(backend.asnumpy(uniform_support(-0.5, 1.5, 101, backend)), want)
    np.testing.assert_array_equal(backend.asnumpy(backend.jit(lambda: uniform_support(-0.5, 1.5, 101, backend))()),
                                  want)


def test_loss_and_mean_hand_computed(backend):
    logits = backend.from_numpy(f32(np.log([[0.25, 0.25, 0.5], [0.1, 0.6, 0.3]])))
    target = backend.from_numpy(f32([[0.0, 1.0, 0.0], [0.5, 0.0, 0.5]]))
    atoms = backend.from_numpy(f32([-1.0, 0.0, 1.0]))
    expected = (-np.log(0.25) + -(0.5 * np.log(0.1) + 0.5 * np.log(0.3))) / 2
    assert_close(categorical_critic_loss(logits, target), expected, rtol=1e-6)
    assert_close(categorical_mean(logits, atoms), [0.25, 0.2], rtol=1e-6, atol=1e-7)
