"""SAC and TD3 losses on hand-computed numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from core_helpers import assert_close, f32

from unilab_jax.core import sac_losses as sac
from unilab_jax.core import td3_losses as td3

jax = pytest.importorskip("jax")


def test_sac_target_and_losses(backend):
    p = lambda *a: [backend.from_numpy(x) for x in f32(*a)]
    r, d, nq1, nq2, nlp = p([1.0, -1.0], [0.9, 0.0], [2.0, 5.0], [3.0, 4.0], [-1.0, 0.5])
    target = sac.sac_target(r, d, nq1, nq2, nlp, 0.2)
    # 1 + .9 * (min(2,3) - .2 * -1) = 2.98;   -1 + 0 * (...) = -1
    assert_close(target, [2.98, -1.0], rtol=1e-6)
    q1, q2 = p([3.0, 0.0], [2.0, -3.0])
    # (.02^2 + 1^2)/2 + (.98^2 + 2^2)/2
    assert_close(sac.sac_critic_loss(q1, q2, target), (0.0004 + 1.0) / 2 + (0.9604 + 4.0) / 2, rtol=1e-6)
    lp = backend.from_numpy(f32([-2.0, 1.0]))
    # mean(alpha * lp - min(q1, q2)) = mean(.2*-2 - 2, .2*1 - -3) = (-2.4 + 3.2) / 2
    assert_close(sac.sac_actor_loss(q1, q2, lp, 0.2), 0.4, rtol=1e-6)
    alpha_arr = backend.from_numpy(np.float32(0.2))
    assert_close(sac.sac_actor_loss(q1, q2, lp, alpha_arr), 0.4, rtol=1e-6)
    # -mean(exp(log_alpha) * (lp + target_entropy)) with log_alpha = log .5, target -2: -.5*mean(-4, -1)
    log_alpha = backend.from_numpy(np.float32(math.log(0.5)))
    assert_close(sac.sac_temperature_loss(log_alpha, lp, -2.0), 1.25, rtol=1e-6)


def test_sac_gradients_go_where_they_should():
    jnp = jax.numpy
    lp = jnp.asarray([-2.0, 1.0])
    # Temperature: d/dlog_alpha = -mean(alpha * (lp + target)) and nothing flows into lp.
    g_alpha, g_lp = jax.grad(sac.sac_temperature_loss, argnums=(0, 1))(jnp.float32(0.0), lp, -2.0)
    assert float(g_alpha) == pytest.approx(2.5)
    np.testing.assert_array_equal(np.asarray(g_lp), 0.0)
    # Actor: alpha is a constant; the gradient reaches the smaller Q only.
    q1, q2 = jnp.asarray([3.0, 0.0]), jnp.asarray([2.0, -3.0])
    g = jax.grad(sac.sac_actor_loss, argnums=(0, 1, 2, 3))(q1, q2, lp, jnp.float32(0.2))
    np.testing.assert_allclose(np.asarray(g[0]), [0.0, 0.0])
    np.testing.assert_allclose(np.asarray(g[1]), [-0.5, -0.5])
    np.testing.assert_allclose(np.asarray(g[2]), [0.1, 0.1], rtol=1e-6)
    assert float(g[3]) == 0.0
    # Critic: the target is a constant.
    g_t = jax.grad(sac.sac_critic_loss, argnums=2)(q1, q2, jnp.asarray([1.0, 1.0]))
    np.testing.assert_array_equal(np.asarray(g_t), 0.0)


def test_td3_smoothing_target_and_losses(backend):
    p = lambda *a: [backend.from_numpy(x) for x in f32(*a)]
    mean_a, noise = p([[0.5, -0.9, 0.0], [0.95, 0.2, -0.1]], [[0.3, -0.05, 1.0], [0.1, -0.7, 0.2]])
    out = td3.td3_target_action(mean_a, noise, noise_clip=0.5)
    # noise clipped to [-.5, .5] -> [[.3, -.05, .5], [.1, -.5, .2]]; sum clipped to [-1, 1]
    assert_close(out, [[0.8, -0.95, 0.5], [1.0, -0.3, 0.1]], rtol=1e-6)
    out2 = td3.td3_target_action(mean_a, noise, noise_clip=0.5, act_limit=0.6)
    assert_close(out2, [[0.6, -0.6, 0.5], [0.6, -0.3, 0.1]], rtol=1e-6)
    r, d, nq1, nq2 = p([1.0, 2.0], [0.99, 0.0], [4.0, 1.0], [3.0, 7.0])
    target = td3.td3_target(r, d, nq1, nq2)
    assert_close(target, [1.0 + 0.99 * 3.0, 2.0], rtol=1e-6)
    q1, q2 = p([3.97, 0.0], [5.0, 2.0])
    assert_close(td3.td3_critic_loss(q1, q2, target), (0 + 4.0) / 2 + (1.03**2 + 0.0) / 2, rtol=1e-5)
    assert_close(td3.td3_actor_loss(q1), -(3.97 + 0.0) / 2, rtol=1e-6)
