"""V-trace against rlax (per sequence, vmapped over B), truncation by segments; APPO by hand."""

from __future__ import annotations

import numpy as np
import pytest
from core_helpers import assert_close, episode_rollout, episode_segments, f32

from unilab_jax import xp as shim
from unilab_jax.core.vtrace import appo_loss, vtrace

jax = pytest.importorskip("jax")
jnp = jax.numpy
rlax = pytest.importorskip("rlax")

T, B = 20, 6
GAMMA = 0.98


def _rollout(seed: int, p_term: float = 0.1, p_trunc: float = 0.0):
    rng = np.random.default_rng(seed)
    v_ext, rewards, next_values, terminated, truncated = episode_rollout(rng, T, B, p_term, p_trunc,
                                                                        final_value_scale=2.0)
    log_rhos = rng.normal(size=(T, B)) * 0.6  # rho spread across both clip thresholds
    discounts = GAMMA * (1.0 - terminated)
    return f32(v_ext[:-1], next_values, rewards, discounts, log_rhos) + (terminated, truncated)


def _rlax_sequence(v_tm1, v_t, r, d, log_rho, lam, clip_rho, clip_pg_rho):
    out = rlax.vtrace_td_error_and_advantage(
        jnp.asarray(v_tm1), jnp.asarray(v_t), jnp.asarray(r), jnp.asarray(d), jnp.exp(jnp.asarray(log_rho)),
        lambda_=lam, clip_rho_threshold=clip_rho, clip_pg_rho_threshold=clip_pg_rho)
    return out.errors + jnp.asarray(v_tm1), out.pg_advantage


@pytest.mark.parametrize("lam, clip_rho, clip_pg_rho", [(1.0, 1.0, 1.0), (0.9, 1.5, 0.8), (0.7, 1.0, 2.0)])
def test_vtrace_matches_rlax_without_truncation(lam, clip_rho, clip_pg_rho):
    values, next_values, rewards, discounts, log_rhos, terminated, truncated = _rollout(seed=int(lam * 10))
    assert terminated.any()
    ref_fn = jax.vmap(lambda *a: _rlax_sequence(*a, lam, clip_rho, clip_pg_rho), in_axes=1, out_axes=1)
    ref = jax.jit(ref_fn)(values, next_values, rewards, discounts, log_rhos)
    jx = shim.get("jax")
    args = [jx.from_numpy(a) for a in (values, next_values, rewards, discounts, log_rhos, terminated)]
    vs, pg = vtrace(*args, lam=lam, clip_rho=clip_rho, clip_pg_rho=clip_pg_rho)
    assert vs.shape == pg.shape == (T, B) and vs.dtype == jnp.float32
    assert_close(vs, ref[0])
    assert_close(pg, ref[1])


def test_vtrace_with_truncation_matches_rlax_on_segments():
    lam, clip_rho, clip_pg_rho = 0.95, 1.0, 1.0
    values, next_values, rewards, discounts, log_rhos, terminated, truncated = _rollout(9, 0.08, 0.08)
    assert truncated.any()
    done = terminated | truncated
    vs, pg = vtrace(values, next_values, rewards, discounts, log_rhos, done, lam, clip_rho, clip_pg_rho)
    # rlax per episode segment (left-padded to length T, which cannot affect a backward recursion),
    # all segments in one vmapped call.
    where = list(episode_segments(done))
    rows = [[np.pad(a[s:e, b], (pad, 0)) for a in (values, next_values, rewards, discounts, log_rhos)]
            for b, s, e, pad in where]
    cols = [np.stack(x) for x in zip(*rows)]
    ref_vs, ref_pg = jax.jit(jax.vmap(lambda *a: _rlax_sequence(*a, lam, clip_rho, clip_pg_rho)))(*cols)
    for i, (b, s, e, pad) in enumerate(where):
        np.testing.assert_allclose(vs[s:e, b], ref_vs[i, pad:], rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(pg[s:e, b], ref_pg[i, pad:], rtol=1e-5, atol=1e-5)


def test_vtrace_on_policy_lambda_one_is_discounted_return():
    # rho == 1, lam == 1, no termination: vs_t is the n-step return bootstrapped from the last value.
    values, next_values, rewards, _, _, _, _ = _rollout(seed=4, p_term=0.0)
    discounts = np.full((T, B), GAMMA, np.float32)
    vs, _ = vtrace(values, next_values, rewards, discounts, np.zeros((T, B), np.float32),
                   np.zeros((T, B), bool))
    ret = next_values[-1].astype(np.float64)
    expected = np.zeros((T, B))
    for t in reversed(range(T)):
        ret = rewards[t] + GAMMA * ret
        expected[t] = ret
    np.testing.assert_allclose(vs, expected, rtol=1e-5, atol=1e-5)


def test_appo_loss_asymmetric_clip_hand_computed(backend):
    new_lp = f32(np.log([1.25, 0.8, 1.0, 0.9]))
    args = [new_lp, *f32([0.0] * 4, [1.0, -1.0, 2.0, -1.0], [0.0, 1.0, 2.0, 3.0], [1.0] * 4, [1.0] * 4)]
    args = [backend.from_numpy(a) for a in args]
    loss, m = appo_loss(*args, clip_eps=0.2, vf_coef=0.5, ent_coef=0.01, normalize_advantages=False)
    # clip range [1/1.2, 1.2]: objectives min(1.25, 1.2)=1.2, min(-.8, -1/1.2)=-.8333, 2, -.9
    policy = -(1.2 - 1.0 / 1.2 + 2.0 - 0.9) / 4
    assert_close(m["policy_loss"], policy, rtol=1e-6)
    assert_close(m["value_loss"], 1.5, rtol=1e-6)
    assert_close(m["clip_fraction"], 0.5, rtol=1e-6)
    assert_close(loss, policy + 0.5 * 1.5 - 0.01, rtol=1e-6)
