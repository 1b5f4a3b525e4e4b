"""SAC Flow's kernels (``core.flow``) and policy (``algos.offpolicy.sacflow``) against values worked out by
hand: the noisy gated Euler chain, its summed Gaussian log-densities, the tanh correction and the gate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.algos.offpolicy import sacflow
from unilab_jax.core import flow, normalizer

NP = shim.get("numpy")
LOG_N01 = -0.5 * math.log(2 * math.pi)  # log N(0; 0, 1)


def _sigmoid(x: float) -> float:
    return 1.0 / (1.0 + math.exp(-x))


def _const_velocity(candidates, gates):
    """Flow-G velocity with step k's candidate and gate logit given as numbers."""
    def velocity(a, k):
        return flow.gated_velocity(a, np.full_like(a, candidates[k]), np.full_like(a, gates[k]))
    return velocity


def test_one_step_chain_by_hand():
    # K = 1, A = 1: a0 = 0.5; z = sigmoid(0) = 0.5; a1 = 0.5 + 1 * 0.5 * (2 - 0.5) + 0.5 * (-1) = 0.75.
    noise = np.array([[0.5, -1.0]], np.float32)
    log_std = np.array([[math.log(0.5)]], np.float32)
    a, log_prob = flow.flow_rollout(_const_velocity([2.0], [0.0]), noise, log_std, 1)
    assert a[0, 0] == pytest.approx(0.75, abs=1e-6)
    # log N(0.5; 0, 1) + log N(0.75; 1.25, 0.5^2) = (-0.125 + LOG_N01) + (-0.5 - log 0.5 + LOG_N01)
    want = -0.125 + LOG_N01 - 0.5 - math.log(0.5) + LOG_N01
    assert log_prob[0] == pytest.approx(want, abs=1e-6)
    action, squashed = flow.squash(a, log_prob)
    assert action[0, 0] == pytest.approx(math.tanh(0.75), abs=1e-6)
    assert squashed[0] == pytest.approx(want - math.log(1 - math.tanh(0.75) ** 2), abs=1e-5)


def test_two_step_chain_by_hand():
    # K = 2 (dt = 0.5), A = 2 (independent columns), std = exp(-1) per step.
    noise = np.array([[1.0, -2.0, 0.5, 0.0, -1.0, 2.0]], np.float32)
    log_std = np.full((1, 2), -1.0, np.float32)
    cands, gates = [1.0, -3.0], [2.0, -1.0]
    a, log_prob = flow.flow_rollout(_const_velocity(cands, gates), noise, log_std, 2)
    s = math.exp(-1.0)
    want_a, want_lp = [], 0.0
    for a0, e1, e2 in [(1.0, 0.5, -1.0), (-2.0, 0.0, 2.0)]:  # the two action columns
        a1 = a0 + 0.5 * _sigmoid(2.0) * (1.0 - a0) + s * e1
        a2 = a1 + 0.5 * _sigmoid(-1.0) * (-3.0 - a1) + s * e2
        want_a.append(a2)
        want_lp += -0.5 * a0 ** 2 + LOG_N01
        for e in (e1, e2):
            want_lp += -0.5 * e ** 2 + 1.0 + LOG_N01  # -log std = +1
    np.testing.assert_allclose(a[0], want_a, atol=1e-5)
    assert log_prob[0] == pytest.approx(want_lp, abs=1e-5)


def test_deterministic_rollout_and_gate_limits():
    # Deterministic: a_0 = 0, no noise; with the gate shut (logit -> -inf) the action never moves,
    # wide open (+inf) each step is the convex mix (1 - dt) a + dt c: c (1 - (1 - dt)^K) from a_0 = 0.
    log_std = np.zeros((1, 1), np.float32)
    shut, _ = flow.flow_rollout(_const_velocity([5.0] * 3, [-60.0] * 3), None, log_std, 3, deterministic=True)
    assert shut[0, 0] == pytest.approx(0.0, abs=1e-12)
    opened, lp = flow.flow_rollout(_const_velocity([5.0] * 3, [60.0] * 3), None, log_std, 3, deterministic=True)
    assert opened[0, 0] == pytest.approx(5.0 * (1 - (2 / 3) ** 3), abs=1e-5)
    assert lp[0] == 0.0
    # A shut gate makes a step pure noise: a_1 = a_0 + std eps whatever the candidate.
    noise = np.array([[0.3, 0.7]], np.float32)
    a, _ = flow.flow_rollout(_const_velocity([100.0], [-60.0]), noise, log_std, 1)
    assert a[0, 0] == pytest.approx(1.0, abs=1e-6)


def test_gate_bounds_the_gradient_through_the_steps():
    """d a_K / d a_0 along the chain is prod_k (1 - dt sigmoid(g_k)) in [0, 1] for any K (Flow-G's point)."""
    jax = pytest.importorskip("jax")
    jnp = jax.numpy
    for k_steps in (1, 4, 16):
        gates = [float(g) for g in np.linspace(-3, 3, k_steps)]

        def final(a0, k_steps=k_steps, gates=gates):
            noise = jnp.concatenate([a0, jnp.zeros((1, k_steps))], axis=-1)
            def velocity(a, k):
                return flow.gated_velocity(a, jnp.full_like(a, 2.0), jnp.full_like(a, gates[k]))
            return flow.flow_rollout(velocity, noise, jnp.zeros((1, 1)), k_steps)[0][0, 0]

        grad = float(jax.grad(final)(jnp.full((1, 1), 0.3))[0, 0])
        want = math.prod(1 - _sigmoid(g) / k_steps for g in gates)
        assert grad == pytest.approx(want, rel=1e-5) and 0.0 < grad <= 1.0


def test_noise_width_is_checked():
    with pytest.raises(ValueError, match="columns"):
        flow.flow_rollout(_const_velocity([0.0] * 2, [0.0] * 2), np.zeros((1, 4), np.float32),
                          np.zeros((1, 2), np.float32), 2)


def test_policy_sample_matches_its_networks_by_hand():
    """``sacflow.sample`` with K = 2: the velocity net sees [normalized obs, a_k, onehot(k)]."""
    cfg = sacflow.SACFlowConfig(actor_hidden=(8,), critic_hidden=(8,), flow_steps=2)
    params = sacflow.init_params(NP.random.key(3), 4, 5, 2, cfg, NP)
    actor = params["actor"]
    # The gate's output bias starts open, the candidate's at zero.
    np.testing.assert_array_equal(actor["velocity"][-1]["b"], [0.0, 0.0, 5.0, 5.0])
    stats = normalizer.stats_init(4, NP)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(3, 4)).astype(np.float32)
    noise = rng.normal(size=(3, sacflow.noise_dim(2))).astype(np.float32)  # a worker's draw: 17 x 2 columns
    action, log_prob = sacflow.sample(actor, stats, obs, noise)

    x = np.asarray(normalizer.normalize(stats, obs))
    log_std = -5.0 + 3.5 * (np.tanh(nets.apply(actor["log_std"], x, "relu")) + 1.0)
    a = noise[:, :2].astype(np.float64)
    lp = np.sum(-0.5 * a ** 2 + LOG_N01, axis=-1)
    for k in range(2):
        code = np.zeros((3, 2), np.float32)
        code[:, k] = 1.0
        out = nets.apply(actor["velocity"], np.concatenate([x, a.astype(np.float32), code], axis=-1), "relu")
        v = (1 / (1 + np.exp(-out[:, 2:]))) * (out[:, :2] - a)
        eps = noise[:, 2 * (k + 1):2 * (k + 2)]
        a = a + 0.5 * v + np.exp(log_std) * eps
        lp += np.sum(-0.5 * eps ** 2 - log_std + LOG_N01, axis=-1)
    lp -= np.sum(np.log(1 - np.tanh(a) ** 2), axis=-1)
    np.testing.assert_allclose(action, np.tanh(a), atol=1e-5)
    np.testing.assert_allclose(log_prob, lp, atol=1e-4)
    # The worker-side act: same action, float32; deterministic ignores the (evaluation's [M, A]) noise.
    weights = {"actor": actor, "obs_norm": stats}
    acted, extras = sacflow.act(weights, obs, noise)
    assert extras == {} and acted.dtype == np.float32
    np.testing.assert_allclose(acted, action, atol=1e-6)
    det, _ = sacflow.act(weights, obs, np.zeros((3, 2), np.float32), deterministic=True)
    assert det.shape == (3, 2) and np.all(np.abs(det) < 1)


def test_config_checks_flow_steps():
    with pytest.raises(ValueError, match="flow_steps"):
        sacflow.SACFlowConfig(flow_steps=0)
    with pytest.raises(ValueError, match="flow_steps"):
        sacflow.SACFlowConfig(flow_steps=sacflow.MAX_FLOW_STEPS + 1)


def test_gate_gradient_is_finite_for_any_logit():
    """A gate logit far below zero (a drifting network output) must give a zero gate and a finite gradient; the
    quotient form 1 / (1 + exp(-x)) gave NaN below about -89 in float32, which made SAC Flow's weights NaN."""
    jax = pytest.importorskip("jax")
    jnp = jax.numpy
    raw = [-1e4, -300.0, -100.0, -89.0, -20.0, 0.0, 3.0, 100.0, 1e4]
    want = np.asarray([_sigmoid(x) if abs(x) < 700 else float(x > 0) for x in raw])
    logits = jnp.asarray(raw, jnp.float32)
    for values in (flow.sigmoid(logits), flow.sigmoid(np.asarray(raw, np.float32))):
        np.testing.assert_allclose(np.asarray(values), want, rtol=1e-6, atol=1e-30)
    a, cand = jnp.full((9,), 0.3, jnp.float32), jnp.full((9,), -2.0, jnp.float32)
    grads = jax.grad(lambda g, c, a: flow.gated_velocity(a, c, g).sum(), argnums=(0, 1, 2))(logits, cand, a)
    for g in grads:
        assert np.isfinite(np.asarray(g)).all()
    assert float(grads[0][0]) == 0.0 and float(grads[1][0]) == 0.0  # a shut gate passes nothing back
