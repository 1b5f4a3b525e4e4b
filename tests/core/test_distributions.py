"""Gaussian and tanh-Gaussian kernels against distrax and float64 numpy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from core_helpers import assert_close, f32, to_np

from unilab_jax import xp as shim
from unilab_jax.core import distributions as D

jax = pytest.importorskip("jax")
jnp = jax.numpy
distrax = pytest.importorskip("distrax")

B, A = 16, 6


def _inputs(seed: int = 0):
    rng = np.random.default_rng(seed)
    mean = rng.normal(size=(B, A)) * 0.5
    log_std = rng.uniform(-1.5, 0.5, size=(B, A))
    pre = rng.uniform(-1.5, 1.5, size=(B, A))  # away from saturation, so distrax's atanh is accurate
    return f32(mean, log_std, pre)


def test_gaussian_log_prob_entropy_kl_match_distrax():
    jx = shim.get("jax")
    mean, log_std, x = _inputs(1)
    mean2, log_std2, _ = _inputs(2)
    p = distrax.MultivariateNormalDiag(jnp.asarray(mean), jnp.exp(jnp.asarray(log_std)))
    q = distrax.MultivariateNormalDiag(jnp.asarray(mean2), jnp.exp(jnp.asarray(log_std2)))
    j = lambda a: jx.from_numpy(a)
    assert_close(D.gaussian_log_prob(j(x), j(mean), j(log_std)), p.log_prob(jnp.asarray(x)))
    assert_close(D.gaussian_entropy(j(log_std)), p.entropy())
    assert_close(D.gaussian_kl(j(mean), j(log_std), j(mean2), j(log_std2)), p.kl_divergence(q))
    assert float(np.min(to_np(D.gaussian_kl(j(mean), j(log_std), j(mean), j(log_std))))) == pytest.approx(0.0)


def test_gaussian_entropy_shapes():
    log_std = np.full((A,), -0.5, np.float32)
    h = D.gaussian_entropy(log_std)
    assert np.shape(h) == ()
    assert float(h) == pytest.approx(A * (-0.5 + 0.5 * math.log(2 * math.pi * math.e)), rel=1e-6)
    assert D.gaussian_entropy(np.broadcast_to(log_std, (B, A))).shape == (B,)


def test_tanh_gaussian_log_prob_matches_distrax():
    mean, log_std, pre = _inputs(3)
    dist = distrax.Transformed(
        distrax.MultivariateNormalDiag(jnp.asarray(mean), jnp.exp(jnp.asarray(log_std))),
        distrax.Block(distrax.Tanh(), 1),
    )
    expected = dist.log_prob(jnp.tanh(jnp.asarray(pre)))
    jx = shim.get("jax")
    got = D.tanh_gaussian_log_prob(jx.from_numpy(pre), jx.from_numpy(mean), jx.from_numpy(log_std))
    assert got.shape == (B,)
    assert_close(got, expected, rtol=1e-5, atol=2e-5)


def test_tanh_gaussian_sample_is_consistent_with_log_prob_and_distrax():
    mean, log_std, _ = _inputs(4)
    eps = f32(np.random.default_rng(5).normal(size=(B, A)).clip(-2, 2))
    action, log_prob = D.tanh_gaussian_sample(mean, log_std, eps)
    u = mean + np.exp(log_std) * eps
    np.testing.assert_allclose(action, np.tanh(u), rtol=1e-6, atol=1e-6)
    assert_close(log_prob, D.tanh_gaussian_log_prob(u, mean, log_std))
    dist = distrax.Transformed(
        distrax.MultivariateNormalDiag(jnp.asarray(mean), jnp.exp(jnp.asarray(log_std))),
        distrax.Block(distrax.Tanh(), 1),
    )
    assert_close(log_prob, dist.log_prob(jnp.asarray(action)), rtol=1e-5, atol=5e-5)
    assert_close(D.tanh_gaussian_entropy_estimate(mean, log_std, eps), -log_prob)


def test_tanh_correction_is_stable_when_saturated():
    # float64 reference of log(1 - tanh(u)^2) = log(sech(u)^2); a naive float32 formula gives -inf/NaN.
    u = np.array([[0.0, 3.0, -8.0, 15.0, -30.0, 60.0, -60.0, -100.0]], np.float32)
    mean = np.zeros_like(u)
    log_std = np.zeros_like(u)
    got = D.tanh_gaussian_log_prob(u, mean, log_std)
    u64 = u.astype(np.float64)
    log_sech2 = 2.0 * (np.log(2.0) - np.abs(u64) - np.log1p(np.exp(-2.0 * np.abs(u64))))
    expected = np.sum(-0.5 * u64**2 - 0.5 * np.log(2 * np.pi) - log_sech2, axis=-1)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, expected, rtol=1e-6)
    assert got.dtype == np.float32
