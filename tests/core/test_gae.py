"""GAE against rlax (no truncation), a hand-computed truncation example and a float64 loop."""

from __future__ import annotations

import numpy as np
import pytest
from core_helpers import assert_close, episode_rollout, episode_segments, f32

from unilab_jax import xp as shim
from unilab_jax.core.gae import gae

jax = pytest.importorskip("jax")
jnp = jax.numpy
rlax = pytest.importorskip("rlax")

T, B = 24, 8


def _rollout(seed: int, p_term: float = 0.1, p_trunc: float = 0.0):
    """A contiguous rollout: next_values[t] == values[t+1] unless the episode ended at t."""
    v_ext, rewards, next_values, terminated, truncated = episode_rollout(np.random.default_rng(seed), T, B, p_term,
                                                                        p_trunc, final_value_scale=3.0)
    return f32(rewards, v_ext[:-1], next_values) + (terminated, truncated, v_ext)


def _loop_reference(rewards, values, next_values, terminated, truncated, gamma, lam):
    """Straightforward float64 loop over t and b (independent of the kernel's vectorisation)."""
    adv = np.zeros(rewards.shape, np.float64)
    for b in range(rewards.shape[1]):
        acc = 0.0
        for t in reversed(range(rewards.shape[0])):
            if terminated[t, b]:
                delta = rewards[t, b] - values[t, b]
            else:
                delta = rewards[t, b] + gamma * next_values[t, b] - values[t, b]
            if terminated[t, b] or truncated[t, b]:
                acc = 0.0
            acc = delta + gamma * lam * acc
            adv[t, b] = acc
    return adv, adv + values


@pytest.mark.parametrize("lam", [0.95, 1.0, 0.0])
def test_gae_matches_rlax_without_truncation(lam):
    gamma = 0.99
    rewards, values, next_values, terminated, truncated, v_ext = _rollout(seed=int(lam * 100))
    assert terminated.any()
    discounts = f32(gamma * (1.0 - terminated))
    rlax_values = f32(v_ext)
    expected = jax.jit(jax.vmap(
        lambda r, d, v: rlax.truncated_generalized_advantage_estimation(r, d, lam, v), in_axes=1, out_axes=1)
    )(jnp.asarray(rewards), jnp.asarray(discounts), jnp.asarray(rlax_values))
    jx = shim.get("jax")
    args = [jx.from_numpy(a) for a in (rewards, values, next_values, terminated, truncated)]
    adv, ret = gae(*args, gamma, lam)
    assert adv.shape == ret.shape == (T, B) and adv.dtype == jnp.float32
    assert_close(adv, expected)
    assert_close(ret, np.asarray(expected) + values)


def test_gae_truncation_hand_computed():
    # One env, 3 steps; the episode is truncated (time limit) at t=1, a new one runs at t=2.
    gamma, lam = 0.5, 0.8
    rewards = f32(np.array([[1.0], [2.0], [3.0]]))
    values = f32(np.array([[10.0], [20.0], [30.0]]))
    next_values = f32(np.array([[20.0], [40.0], [50.0]]))  # 40 = V(final obs before reset)
    terminated = np.array([[False], [False], [False]])
    truncated = np.array([[False], [True], [False]])
    # t=2: delta = 3 + .5*50 - 30 = -2                        A2 = -2
    # t=1: delta = 2 + .5*40 - 20 = 2, trace cut               A1 = 2
    # t=0: delta = 1 + .5*20 - 10 = 1                          A0 = 1 + .5*.8*2 = 1.8
    adv, ret = gae(rewards, values, next_values, terminated, truncated, gamma, lam)
    np.testing.assert_allclose(adv[:, 0], [1.8, 2.0, -2.0], rtol=1e-6)
    np.testing.assert_allclose(ret[:, 0], [11.8, 22.0, 28.0], rtol=1e-6)
    # The same step terminated instead: no bootstrap from 40.
    adv_t, _ = gae(rewards, values, next_values, truncated, terminated, gamma, lam)
    np.testing.assert_allclose(adv_t[:, 0], [1.0 + 0.4 * -18.0, -18.0, -2.0], rtol=1e-6)


def test_gae_with_truncation_matches_loop_and_rlax_segments():
    gamma, lam = 0.97, 0.9
    rewards, values, next_values, terminated, truncated, _ = _rollout(seed=7, p_term=0.08, p_trunc=0.08)
    assert truncated.any() and terminated.any()
    adv, ret = gae(rewards, values, next_values, terminated, truncated, gamma, lam)
    ref_adv, ref_ret = _loop_reference(rewards, values, next_values, terminated, truncated, gamma, lam)
    assert_close(adv, ref_adv)
    assert_close(ret, ref_ret)
    # rlax on each episode segment separately, bootstrapping the last step from next_values. Segments
    # are left-padded to length T (padding before a segment cannot reach it in a backward recursion)
    # and batched through one vmapped call.
    done = terminated | truncated
    where = list(episode_segments(done))
    rows = [(np.pad(rewards[s:e, b], (pad, 0)), np.pad(gamma * (1.0 - terminated[s:e, b]), (pad, 0)),
             np.pad(np.concatenate([values[s:e, b], next_values[e - 1:e, b]]), (pad, 0))) for b, s, e, pad in where]
    r, d, v = (jnp.asarray(np.stack(x), jnp.float32) for x in zip(*rows))
    ref = jax.jit(jax.vmap(lambda r, d, v: rlax.truncated_generalized_advantage_estimation(r, d, lam, v)))
    seg = np.asarray(ref(r, d, v))
    for i, (b, s, e, pad) in enumerate(where):
        np.testing.assert_allclose(adv[s:e, b], seg[i, pad:], rtol=1e-5, atol=1e-5)


def test_gae_accepts_float_flags(backend):
    rewards, values, next_values, terminated, truncated, _ = _rollout(seed=3, p_term=0.1, p_trunc=0.1)
    fb = lambda a: backend.from_numpy(np.asarray(a, np.float32))
    adv_bool = gae(*(backend.from_numpy(a) for a in (rewards, values, next_values, terminated, truncated)),
                   0.99, 0.95)
    adv_float = gae(fb(rewards), fb(values), fb(next_values), fb(terminated), fb(truncated), 0.99, 0.95)
    assert_close(adv_bool, adv_float, rtol=0, atol=0)
