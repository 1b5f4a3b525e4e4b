"""PPO loss against rlax's clipped surrogate and hand-computed numbers; the KL-adaptive lr rule."""

from __future__ import annotations

import numpy as np
import pytest
from core_helpers import assert_close, f32, to_np

from unilab_jax import xp as shim
from unilab_jax.core.ppo_losses import kl_adaptive_lr, ppo_loss

jax = pytest.importorskip("jax")
jnp = jax.numpy
rlax = pytest.importorskip("rlax")

N = 64


def _batch(seed: int):
    rng = np.random.default_rng(seed)
    old_lp = rng.normal(size=N) - 2.0
    new_lp = old_lp + rng.normal(size=N) * 0.3  # ratios spread well beyond 1 +- 0.2
    adv = rng.normal(size=N) * 2.0 + 0.5
    old_v = rng.normal(size=N)
    new_v = old_v + rng.normal(size=N) * 0.5
    returns = old_v + rng.normal(size=N)
    entropy = rng.uniform(0.5, 2.0, size=N)
    return f32(new_lp, old_lp, adv, new_v, old_v, returns, entropy)


@pytest.mark.parametrize("normalize", [False, True])
def test_policy_part_matches_rlax(normalize):
    new_lp, old_lp, adv, new_v, old_v, returns, entropy = _batch(0)
    jx = shim.get("jax")
    args = [jx.from_numpy(a) for a in (new_lp, old_lp, adv, new_v, old_v, returns, entropy)]
    loss, metrics = ppo_loss(*args, clip_eps=0.2, value_clip=None, vf_coef=0.0, ent_coef=0.0,
                             normalize_advantages=normalize)
    ratios = jnp.exp(jnp.asarray(new_lp) - jnp.asarray(old_lp))
    assert float(jnp.mean(jnp.abs(ratios - 1) > 0.2)) > 0.2  # the clip is exercised
    ref_adv = (adv - adv.mean()) / (adv.std(ddof=1) + 1e-8) if normalize else adv
    expected = rlax.clipped_surrogate_pg_loss(ratios, jnp.asarray(ref_adv, jnp.float32), 0.2)
    assert_close(loss, expected)
    assert_close(metrics["policy_loss"], expected)


def test_value_entropy_and_metrics_hand_computed():
    new_lp = f32(np.log([1.0, 1.5, 0.5, 1.1]))
    old_lp = f32(np.zeros(4))
    adv = f32([1.0, 2.0, -1.0, -2.0])
    new_v = f32([1.0, 2.0, 0.0, 0.5])
    old_v = f32([0.0, 2.5, 0.0, 0.0])
    returns = f32([2.0, 3.0, -1.0, 0.0])
    entropy = f32([1.0, 2.0, 3.0, 4.0])
    # ratios 1, 1.5, 0.5, 1.1 with eps 0.2: objectives min(r A, clip(r) A) = 1, 2.4, -0.8, -2.2
    policy = -(1.0 + 2.4 - 0.8 - 2.2) / 4
    # unclipped squared errors: 1, 1, 1, .25
    v_plain = (1 + 1 + 1 + 0.25) / 4
    # clipped (c=0.3): v_clip = 0.3, 2.2, 0, 0.3 -> errors 2.89, .64, 1, .09; max -> 2.89, 1, 1, .25
    v_clipped = (2.89 + 1 + 1 + 0.25) / 4
    kl = np.mean([r - 1 - np.log(r) for r in (1.0, 1.5, 0.5, 1.1)])
    for value_clip, v_loss in ((None, v_plain), (0.3, v_clipped)):
        loss, m = ppo_loss(new_lp, old_lp, adv, new_v, old_v, returns, entropy, clip_eps=0.2,
                           value_clip=value_clip, vf_coef=0.5, ent_coef=0.01, normalize_advantages=False)
        np.testing.assert_allclose(float(loss), policy + 0.5 * v_loss - 0.01 * 2.5, rtol=1e-6)
        np.testing.assert_allclose(float(m["policy_loss"]), policy, rtol=1e-6)
        np.testing.assert_allclose(float(m["value_loss"]), v_loss, rtol=1e-6)
        np.testing.assert_allclose(float(m["entropy"]), 2.5, rtol=1e-6)
        np.testing.assert_allclose(float(m["approx_kl"]), kl, rtol=1e-5)
        np.testing.assert_allclose(float(m["clip_fraction"]), 0.5, rtol=1e-6)


def test_policy_gradient_vanishes_outside_the_clip():
    jx = shim.get("jax")
    new_lp = jx.from_numpy(f32(np.log([1.5, 0.5, 1.5, 0.5])))
    rest = [jx.from_numpy(a) for a in f32([0.0] * 4, [1.0, -1.0, -1.0, 1.0], [0.0] * 4, [0.0] * 4,
                                          [0.0] * 4, [0.0] * 4)]

    def f(lp):
        return ppo_loss(lp, *rest, clip_eps=0.2, value_clip=None, vf_coef=0.0, ent_coef=0.0,
                        normalize_advantages=False)[0]

    g = np.asarray(jax.grad(f)(new_lp))
    # r=1.5, A>0 and r=0.5, A<0 are clipped (zero gradient); the pessimistic others are not.
    np.testing.assert_allclose(g, [0.0, 0.0, 1.5 / 4, -0.5 / 4], rtol=1e-6)


@pytest.mark.parametrize("kl, expected", [
    (0.05, 1e-3 / 1.5),   # kl > 2 * desired: decrease
    (0.004, 1e-3 * 1.5),  # 0 < kl < desired / 2: increase
    (0.0, 1e-3),          # kl == 0: unchanged (rsl_rl requires kl > 0)
    (0.015, 1e-3),        # in between: unchanged
    (0.02, 1e-3),         # exactly 2 * desired: unchanged
])
def test_kl_adaptive_lr_branches(backend, kl, expected):
    lr = backend.from_numpy(np.float32(1e-3))
    out = kl_adaptive_lr(lr, backend.from_numpy(np.float32(kl)), desired_kl=0.01)
    np.testing.assert_allclose(float(to_np(out)), expected, rtol=1e-6)


def test_kl_adaptive_lr_limits_and_jit():
    assert float(kl_adaptive_lr(1.2e-5, 1.0, 0.01)) == pytest.approx(1e-5)
    assert float(kl_adaptive_lr(9e-3, 1e-4, 0.01)) == pytest.approx(1e-2)
    assert float(kl_adaptive_lr(2e-3, 1e-4, 0.01, factor=2.0, max_lr=3e-3)) == pytest.approx(3e-3)
    f = jax.jit(lambda lr, kl: kl_adaptive_lr(lr, kl, 0.01))
    lr = jnp.float32(1e-3)
    for kl, expected in ((0.05, 1e-3 / 1.5), (0.001, 1e-3 * 1.5), (0.01, 1e-3)):
        out = f(lr, jnp.float32(kl))
        assert out.dtype == jnp.float32
        np.testing.assert_allclose(float(out), expected, rtol=1e-6)


def test_metrics_are_scalars(backend):
    batch = _batch(3)
    args = [backend.from_numpy(a) for a in batch]
    loss, m = ppo_loss(*args, 0.2, 0.2, 1.0, 0.005)
    assert set(m) == {"policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction"}
    for v in [loss, *m.values()]:
        assert tuple(v.shape) == ()
    log_ratio = batch[0].astype(np.float64) - batch[1]
    assert_close(m["approx_kl"], np.mean(np.expm1(log_ratio) - log_ratio))
