"""Off-policy algorithms without JAX: module contract, worker-side ``act`` and hand-computed losses.

Everything here runs on the shim's numpy backend (what the workers use), so nothing compiles.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from unilab_jax import algos
from unilab_jax import xp as shim
from unilab_jax.algos.offpolicy import fastsac, flashsac, sac, td3
from unilab_jax.core import normalizer

NP = shim.get("numpy")
NAMES = ("sac", "td3", "fastsac", "flashsac")
OBS, COBS, A = 5, 7, 3


def _f32(x):
    return np.asarray(x, np.float32)


def _weights(mod, config):
    params = mod.init_params(NP.random.key(0), OBS, COBS, A, config, NP)
    w = {"actor": params["actor"], "obs_norm": normalizer.stats_init(OBS, NP)}
    if mod is td3:
        w["explore_std"] = np.float32(config.explore_std)
    return w


def test_modules_declare_the_contract_and_import_without_jax():
    code = ("import sys, unilab_jax.algos as a\n"
            f"mods = [a.get(n) for n in {NAMES!r}]\n"
            "assert 'jax' not in sys.modules, 'an algorithm module imported jax'\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
    for name in NAMES:
        mod = algos.get(name)
        assert mod.SYNC == "async" and mod.BUFFER == "replay"
        cfg = mod.Config()
        for field in ("actor_hidden", "critic_hidden", "actor_learning_rate", "critic_learning_rate", "batch_size",
                      "utd", "updates_per_call", "replay_capacity", "learning_starts", "publish_every", "gamma",
                      "tau", "normalize_obs"):
            assert hasattr(cfg, field), (name, field)
        assert mod.extras(A) == {}
        with pytest.raises(ValueError):
            mod.make_learner("no-such-platform", cfg, None)
    assert isinstance(flashsac.NOISE_HOLD_STEPS, int) and flashsac.NOISE_HOLD_STEPS >= 1


@pytest.mark.parametrize("name", NAMES)
def test_act_on_numpy(name):
    mod = algos.get(name)
    w = _weights(mod, mod.Config(actor_hidden=(16, 16)))
    rng = np.random.default_rng(0)
    obs = _f32(rng.normal(size=(9, OBS)) * 3)
    noise = _f32(rng.normal(size=(9, A)) * 3)
    action, extras = mod.act(w, obs, noise, False)
    assert action.dtype == np.float32 and action.shape == (9, A) and extras == {}
    assert np.all(np.abs(action) <= 1.0) and np.all(np.isfinite(action))
    det1, _ = mod.act(w, obs, noise, True)
    det2, _ = mod.act(w, obs, np.zeros_like(noise), True)
    np.testing.assert_array_equal(det1, det2)  # deterministic ignores the noise
    assert not np.allclose(action, det1)


def test_td3_act_adds_clipped_scaled_noise():
    w = _weights(td3, td3.Config(actor_hidden=(8,)))
    obs = _f32(np.random.default_rng(1).normal(size=(4, OBS)))
    noise = _f32([[0.5, -1.0, 20.0]] * 4)
    mean, _ = td3.act(w, obs, noise, True)
    action, _ = td3.act(w, obs, noise, False)
    np.testing.assert_allclose(action, np.clip(mean + 0.1 * noise, -1, 1), rtol=1e-6)


# ---------------------------------------------------------------------------------------------
# Hand-computed targets and losses
# ---------------------------------------------------------------------------------------------
def _case():
    """A tiny batch (B=2) with non-trivial normalizer statistics and a constant-output actor."""
    rng = np.random.default_rng(2)
    mb = {
        "obs": _f32(rng.normal(size=(2, OBS))), "critic_obs": _f32(rng.normal(size=(2, COBS))),
        "action": _f32(rng.uniform(-1, 1, (2, A))), "reward": _f32([1.5, -0.5]),
        "next_obs": _f32(rng.normal(size=(2, OBS))), "next_critic_obs": _f32(rng.normal(size=(2, COBS))),
        # row 0 is truncated (bootstraps), row 1 terminated (no bootstrap)
        "terminated": _f32([0.0, 1.0]), "truncated": _f32([1.0, 0.0]),
    }
    norms = sac.Norms(
        normalizer.RunningStats(_f32(rng.normal(size=OBS)), _f32(rng.uniform(0.5, 2, OBS)), _f32(10.0)),
        normalizer.RunningStats(_f32(rng.normal(size=COBS)), _f32(rng.uniform(0.5, 2, COBS)), _f32(10.0)),
        _f32(1.0))
    mean_b, raw_b = _f32([0.3, -0.2, 0.8]), _f32([0.1, -0.4, 0.0])
    actor = [{"w": np.zeros((OBS, 2 * A), np.float32), "b": np.concatenate([mean_b, raw_b])}]
    wq = _f32(rng.normal(size=(2, COBS + A, 1)))
    bq = _f32([[[0.5]], [[-0.25]]])
    critic = [{"w": wq, "b": bq}]
    eps = _f32(rng.normal(size=(2, A)))
    return mb, norms, actor, critic, mean_b, raw_b, wq, bq, eps


def _hand_norm(stats, x):
    return np.clip((x - stats.mean) / np.sqrt(stats.var.astype(np.float64) + 1e-8), -10, 10)


def test_sac_critic_target_matches_hand_computation():
    mb, norms, actor, critic, mean_b, raw_b, wq, bq, eps = _case()
    gamma, log_alpha = 0.9, _f32(math.log(0.3))
    y = sac.critic_target(critic, actor, log_alpha, norms, mb, eps, gamma)
    # by hand, float64
    log_std = -5.0 + 0.5 * 7.0 * (np.tanh(raw_b.astype(np.float64)) + 1.0)
    u = mean_b + np.exp(log_std) * eps
    a_next = np.tanh(u)
    log_prob = np.sum(-0.5 * eps**2 - log_std - 0.5 * np.log(2 * np.pi), -1) - np.sum(np.log(1 - np.tanh(u) ** 2), -1)
    x = np.concatenate([_hand_norm(norms.critic, mb["next_critic_obs"]), a_next], -1)
    q = np.stack([x @ wq[i, :, 0] + bq[i, 0, 0] for i in range(2)])
    soft_v = np.minimum(q[0], q[1]) - 0.3 * log_prob
    expected = mb["reward"] + gamma * (1 - mb["terminated"]) * soft_v
    np.testing.assert_allclose(y, expected, rtol=2e-5, atol=2e-5)
    assert y[1] == pytest.approx(-0.5)  # terminated: no bootstrap, truncated row 0 bootstraps
    # The critic loss against that target: sum over the twins of the mean squared error.
    loss, metrics = sac.critic_loss(critic, critic, actor, log_alpha, norms, mb, eps, sac.Config(gamma=gamma))
    xq = np.concatenate([_hand_norm(norms.critic, mb["critic_obs"]), mb["action"]], -1)
    qs = np.stack([xq @ wq[i, :, 0] + bq[i, 0, 0] for i in range(2)])
    assert float(loss) == pytest.approx(float(np.mean((qs[0] - expected) ** 2) + np.mean((qs[1] - expected) ** 2)),
                                        rel=2e-5)
    assert float(metrics["target_mean"]) == pytest.approx(float(np.mean(expected)), rel=2e-5, abs=2e-5)
    # Reward normalisation divides the reward only.
    y2 = sac.critic_target(critic, actor, log_alpha, norms._replace(reward_scale=_f32(2.0)), mb, eps, gamma)
    np.testing.assert_allclose(y2, expected - mb["reward"] / 2, rtol=2e-5, atol=2e-5)


def test_sac_actor_loss_matches_hand_computation():
    mb, norms, actor, critic, mean_b, raw_b, wq, bq, eps = _case()
    loss, (metrics, log_prob) = sac.actor_loss(actor, critic, _f32(math.log(0.3)), norms, mb, eps, sac.Config())
    log_std = -5.0 + 3.5 * (np.tanh(raw_b.astype(np.float64)) + 1.0)
    u = mean_b + np.exp(log_std) * eps
    lp = np.sum(-0.5 * eps**2 - log_std - 0.5 * np.log(2 * np.pi), -1) - np.sum(np.log(1 - np.tanh(u) ** 2), -1)
    x = np.concatenate([_hand_norm(norms.critic, mb["critic_obs"]), np.tanh(u)], -1)
    q = np.minimum(*[x @ wq[i, :, 0] + bq[i, 0, 0] for i in range(2)])
    assert float(loss) == pytest.approx(float(np.mean(0.3 * lp - q)), rel=2e-5, abs=2e-5)
    np.testing.assert_allclose(log_prob, lp, rtol=2e-5, atol=2e-5)


def test_td3_target_matches_hand_computation():
    mb, norms, _, critic, mean_b, _, wq, bq, eps = _case()
    actor = [{"w": np.zeros((OBS, A), np.float32), "b": _f32([0.3, -0.95, 0.8])}]
    cfg = td3.Config(gamma=0.8, policy_noise=0.2, noise_clip=0.5)
    eps = _f32([[0.5, -3.0, 1.0], [4.0, 0.1, -0.2]])
    y = td3.critic_target(actor, critic, norms, mb, eps, cfg)
    a_next = np.clip(np.tanh(actor[0]["b"]) + np.clip(0.2 * eps, -0.5, 0.5), -1, 1)
    x = np.concatenate([_hand_norm(norms.critic, mb["next_critic_obs"]), a_next], -1)
    q = np.minimum(*[x @ wq[i, :, 0] + bq[i, 0, 0] for i in range(2)])
    np.testing.assert_allclose(y, mb["reward"] + 0.8 * (1 - mb["terminated"]) * q, rtol=2e-5, atol=2e-5)


def test_categorical_target_uses_the_smaller_critic_and_keeps_the_mean():
    mb, norms, actor, _, mean_b, raw_b, _, _, eps = _case()
    cfg = fastsac.Config(num_atoms=11, v_min=-10.0, v_max=10.0, gamma=0.5)
    atoms = np.linspace(-10, 10, 11)
    # Critic 0 puts its mass on atom 3 (value -4), critic 1 on atom 8 (value 6): input-independent logits.
    logits = np.full((2, 1, 11), -30.0, np.float32)
    logits[0, 0, 3] = logits[1, 0, 8] = 30.0
    critic = [{"w": np.zeros((2, COBS + A, 11), np.float32), "b": logits}]
    log_alpha = _f32(math.log(0.1))
    target = fastsac.categorical_target(critic, actor, log_alpha, norms, mb, eps, cfg)
    assert target.shape == (2, 11)
    np.testing.assert_allclose(target.sum(-1), 1.0, rtol=1e-5)
    log_std = -5.0 + 3.5 * (np.tanh(raw_b.astype(np.float64)) + 1.0)
    u = mean_b + np.exp(log_std) * eps
    lp = np.sum(-0.5 * eps**2 - log_std - 0.5 * np.log(2 * np.pi), -1) - np.sum(np.log(1 - np.tanh(u) ** 2), -1)
    d = 0.5 * (1 - mb["terminated"])
    # The L2 projection keeps the mean of r - d alpha log pi + d Z' (inside the support); Z' = -4 (cdq).
    expected = mb["reward"] + d * (-4.0 - 0.1 * lp)
    np.testing.assert_allclose(target @ atoms, expected, rtol=1e-4, atol=1e-4)
    no_cdq = fastsac.categorical_target(critic, actor, log_alpha, norms, mb, eps,
                                        fastsac.Config(num_atoms=11, v_min=-10.0, v_max=10.0, gamma=0.5,
                                                       use_cdq=False))
    np.testing.assert_allclose(no_cdq @ atoms, mb["reward"] + d * (1.0 - 0.1 * lp), rtol=1e-4, atol=1e-4)
    for use_cdq, dense in ((True, target), (False, no_cdq)):  # the O(B K) projection: the same target
        prefix = fastsac.categorical_target(critic, actor, log_alpha, norms, mb, eps, fastsac.Config(
            num_atoms=11, v_min=-10.0, v_max=10.0, gamma=0.5, use_cdq=use_cdq, projection="prefix"))
        np.testing.assert_allclose(prefix, dense, atol=1e-6)
    with pytest.raises(ValueError, match="projection"):
        fastsac.Config(projection="sparse")


def test_flash_networks_are_norm_bounded_on_numpy():
    cfg = flashsac.Config(actor_hidden=(16, 16), critic_hidden=(16, 16), num_atoms=11)
    params = flashsac.init_params(NP.random.key(3), OBS, COBS, A, cfg, NP)
    for net in (params["actor"], params["critic"]):
        for layer in net:
            np.testing.assert_allclose(np.linalg.norm(layer["w"], axis=-2), 1.0, rtol=1e-5)
    assert params["critic"][0]["w"].shape == (2, COBS + A + 1, 16)  # ensemble, constant input feature
    out = flashsac.flash_apply(params["critic"], _f32(np.random.default_rng(0).normal(size=(4, COBS + A))))
    assert out.shape == (2, 4, 11)
    # Projection: any matrix ends with unit-norm columns; gains and biases untouched.
    messy = [{"w": _f32(np.random.default_rng(1).normal(size=(6, 4)) * 7), "g": _f32(np.full(4, 3.0)),
              "o": _f32(np.ones(4))}]
    projected = flashsac.project_params(messy)
    np.testing.assert_allclose(np.linalg.norm(projected[0]["w"], axis=0), 1.0, rtol=1e-5)
    np.testing.assert_array_equal(projected[0]["g"], messy[0]["g"])
    # Reward scale: rms(r) / (1 - gamma).
    stats = normalizer.stats_update(normalizer.stats_init(1, NP), _f32([[1.0], [3.0]]))
    assert float(flashsac.reward_scale(stats, cfg)) == pytest.approx(math.sqrt(5.0) / (1 - cfg.gamma), rel=1e-5)


@pytest.mark.parametrize("name", NAMES)
def test_configs_apply_overrides_and_reject_bad_values(name):
    from unilab_jax.config import ConfigError, apply_overrides

    mod = algos.get(name)
    cfg = apply_overrides(mod.Config(), ["batch_size=64", "critic_hidden=(32, 32)", "utd=0.5"])
    assert (cfg.batch_size, cfg.critic_hidden, cfg.utd) == (64, (32, 32), 0.5)
    with pytest.raises(ConfigError):
        apply_overrides(mod.Config(), ["no_such_key=1"])
    with pytest.raises(ValueError):
        apply_overrides(mod.Config(), ["updates_per_call=0"])
    with pytest.raises(ValueError):
        mod.Config(tau=0.0)
