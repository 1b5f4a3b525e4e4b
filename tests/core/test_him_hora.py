"""HIM and HORA kernels on hand-computed numbers; the temporal convolution against jax's own conv."""

from __future__ import annotations

import math

import numpy as np
import pytest
from core_helpers import assert_close, f32, to_np

from unilab_jax import nets_temporal
from unilab_jax import xp as shim
from unilab_jax.core import adaptation as hora
from unilab_jax.core import him

jax = pytest.importorskip("jax")


def test_sinkhorn_one_iteration_by_hand(backend):
    # eps = 1, scores = log [[3, 1], [1, 1]]: Q0 = [[3, 1], [1, 1]] / 6. Columns to 1/K = 1/2:
    # [[3/8, 1/4], [1/8, 1/4]]; rows to 1/B = 1/2: [[3/10, 1/5], [1/6, 1/3]]; times B = 2.
    scores = backend.from_numpy(f32(np.log([[3.0, 1.0], [1.0, 1.0]])))
    q = him.sinkhorn(scores, n_iters=1, eps=1.0)
    assert_close(q, [[0.6, 0.4], [1 / 3, 2 / 3]], rtol=1e-5)
    # A constant shift of every score changes nothing (the first step normalises the total mass).
    assert_close(him.sinkhorn(scores + 5.0, n_iters=1, eps=1.0), q, rtol=1e-5)


def test_sinkhorn_marginals_and_no_overflow(backend):
    rng = np.random.default_rng(0)
    b, k = 12, 4
    scores = backend.from_numpy(f32(rng.normal(size=(b, k))))
    q = to_np(him.sinkhorn(scores, n_iters=50, eps=0.5))
    # Every sample's code is a distribution; every prototype gets an equal share B/K of the batch.
    np.testing.assert_allclose(q.sum(axis=1), np.ones(b), rtol=1e-5)
    np.testing.assert_allclose(q.sum(axis=0), np.full(k, b / k), rtol=1e-3)
    assert (q > 0).all()
    # Three iterations (HIMLoco's setting) already get the rows exactly and the columns roughly.
    q3 = to_np(him.sinkhorn(scores, n_iters=3, eps=0.5))
    np.testing.assert_allclose(q3.sum(axis=1), np.ones(b), rtol=1e-5)
    assert np.abs(q3.sum(axis=0) - b / k).max() < 0.5
    # scores / eps = 400: exp would overflow float32; the log-domain iteration does not.
    big = to_np(him.sinkhorn(backend.from_numpy(f32(rng.normal(size=(b, k)) * 20.0)), n_iters=3, eps=0.05))
    assert np.isfinite(big).all()
    np.testing.assert_allclose(big.sum(axis=1), np.ones(b), rtol=1e-5)


def test_swapped_prediction_by_hand(backend):
    # Prototypes = identity, so scores = latents. Source scores log [[3, 1], [1, 1]] (eps 1, one
    # iteration) give codes [[.6, .4], [1/3, 2/3]] (test above); zero target scores give uniform codes
    # and uniform predictions log(1/2). Source predictions: log softmax rows [3/4, 1/4] and [1/2, 1/2].
    z_s = backend.from_numpy(f32(np.log([[3.0, 1.0], [1.0, 1.0]])))
    z_t = backend.from_numpy(f32(np.zeros((2, 2))))
    protos = backend.from_numpy(f32(np.eye(2)))
    loss, metrics = him.swapped_prediction_loss(z_s, z_t, protos, temperature=1.0, n_iters=1, eps=1.0)
    q_s_log_p_t = 2.0 * math.log(0.5)  # codes sum to 1 per row, two rows
    q_t_log_p_s = 0.5 * (math.log(0.75) + math.log(0.25) + 2.0 * math.log(0.5))
    expected = -0.5 * (q_s_log_p_t + q_t_log_p_s) / 4.0  # mean over B * K = 4 entries
    assert_close(loss, expected, rtol=1e-5)
    assert_close(metrics["swap_loss"], expected, rtol=1e-5)
    assert_close(metrics["prototype_usage"], 1.0)  # arg-max codes: sample 0 -> 0, sample 1 -> 1


def test_swapped_prediction_gradient_treats_codes_as_constants():
    jnp = jax.numpy
    rng = np.random.default_rng(1)
    unit = lambda *s: jnp.asarray(him.l2_normalize(rng.normal(size=s).astype(np.float32)))
    z_s, z_t, protos = unit(8, 4), unit(8, 4), unit(5, 4)
    temp = 0.7
    grad = jax.grad(lambda a, b, p: him.swapped_prediction_loss(a, b, p, temperature=temp)[0], argnums=(0, 1, 2))
    got = grad(z_s, z_t, protos)
    q_s, q_t = him.sinkhorn(z_s @ protos.T), him.sinkhorn(z_t @ protos.T)

    def fixed_codes(a, b, p):  # the same loss with the codes as precomputed constants
        lp_s = jax.nn.log_softmax(a @ p.T / temp)
        lp_t = jax.nn.log_softmax(b @ p.T / temp)
        return -0.5 * jnp.mean(q_s * lp_t + q_t * lp_s)

    want = jax.grad(fixed_codes, argnums=(0, 1, 2))(z_s, z_t, protos)
    for g, w in zip(got, want):
        np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-5, atol=1e-7)
    assert float(jnp.abs(want[0]).max()) > 0  # not vacuous


def test_velocity_and_l2(backend):
    v = backend.from_numpy(f32([[1.0, 2.0], [0.0, -1.0]]))
    t = backend.from_numpy(f32([[0.0, 0.0], [0.0, 1.0]]))
    assert_close(him.velocity_loss(v, t), (1.0 + 4.0 + 0.0 + 4.0) / 4.0)
    x = backend.from_numpy(f32([[3.0, 4.0], [0.0, 0.0]]))
    assert_close(him.l2_normalize(x), [[0.6, 0.8], [0.0, 0.0]])  # a zero vector stays zero, no NaN


def test_adaptation_loss_by_hand(backend):
    pred = backend.from_numpy(f32([[0.5, -0.5], [0.0, 1.0]]))
    target = backend.from_numpy(f32([[0.0, 0.0], [1.0, 1.0]]))
    loss, metrics = hora.adaptation_loss(pred, target)
    assert_close(loss, (0.25 + 0.25 + 1.0 + 0.0) / 4.0)
    assert_close(metrics["z_mse"], 0.375)
    assert_close(metrics["z_target_var"], 0.25)  # target mean (.5, .5): every centred entry is +-.5


def test_only_the_prediction_gets_gradients():
    jnp = jax.numpy
    pred, target = jnp.asarray([[0.5, -0.5]]), jnp.asarray([[0.0, 1.0]])
    g_pred, g_target = jax.grad(lambda p, t: hora.adaptation_loss(p, t)[0], argnums=(0, 1))(pred, target)
    np.testing.assert_allclose(np.asarray(g_pred), [[0.5, -1.5]])  # 2 (p - t) / N
    np.testing.assert_allclose(np.asarray(g_target), 0.0)
    g_v, g_t = jax.grad(him.velocity_loss, argnums=(0, 1))(pred, target)
    np.testing.assert_allclose(np.asarray(g_v), [[0.5, -1.5]])
    np.testing.assert_allclose(np.asarray(g_t), 0.0)


@pytest.mark.parametrize("stride", [1, 2, 3])
def test_conv1d_matches_jax_conv(stride):
    rng = np.random.default_rng(stride)
    x = rng.normal(size=(3, 13, 4)).astype(np.float32)
    params = {"w": rng.normal(size=(5, 4, 6)).astype(np.float32), "b": rng.normal(size=6).astype(np.float32)}
    got = nets_temporal.conv1d(params, x, stride=stride)
    want = jax.lax.conv_general_dilated(x, params["w"], (stride,), "VALID",
                                        dimension_numbers=("NWC", "WIO", "NWC")) + params["b"]
    assert got.shape == ((3, (13 - 5) // stride + 1, 6))
    np.testing.assert_allclose(got, np.asarray(want), rtol=1e-5, atol=1e-5)


def test_adaptation_module_shapes_and_history_check():
    np_ = shim.get("numpy")
    params = nets_temporal.adaptation_init(np_.random.key(0), frame_dim=7, z_dim=8, history_len=30, xp=np_)
    # HORA's kernels (9 stride 2, 5, 5): 30 -> 11 -> 7 -> 3 frames of 32 channels.
    assert params["proj"][0]["w"].shape == (3 * 32, 8)
    out = nets_temporal.adaptation_apply(params, np.ones((2, 5, 30, 7), np.float32))
    assert out.shape == (2, 5, 8)
    with pytest.raises(ValueError, match="too short"):
        nets_temporal.adaptation_init(np_.random.key(0), 7, 8, history_len=24, xp=np_)
