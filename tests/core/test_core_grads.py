"""Gradients of the PPO and SAC (and C51) losses through small models agree between jax and mlx."""

from __future__ import annotations

import numpy as np
import pytest
from core_helpers import assert_close, f32, put, to_np

from unilab_jax import xp as shim
from unilab_jax.core import c51, distributions
from unilab_jax.core import ppo_losses as ppo
from unilab_jax.core import sac_losses as sac

N, D, A, K = 32, 6, 3, 11


def _ppo_params_and_batch():
    rng = np.random.default_rng(0)
    params = {"w": rng.normal(size=(D, A)) * 0.3, "log_std": rng.uniform(-1.0, 0.0, A),
              "wv": rng.normal(size=(D, 1)) * 0.3}
    obs = rng.normal(size=(N, D))
    actions = obs @ params["w"] + rng.normal(size=(N, A)) * 0.5
    old_lp = rng.normal(size=N) * 0.5 - 3.0
    batch = {"obs": obs, "actions": actions, "old_lp": old_lp, "adv": rng.normal(size=N),
             "old_v": rng.normal(size=N), "returns": rng.normal(size=N)}
    return f32_tree(params), f32_tree(batch)


def f32_tree(tree):
    return shim.tree_map(lambda a: f32(a), tree)


def _ppo_objective(params, batch):
    xp = shim.namespace(params["w"])
    mean = xp.matmul(batch["obs"], params["w"])
    log_std = params["log_std"] + xp.zeros_like(mean)
    new_lp = distributions.gaussian_log_prob(batch["actions"], mean, log_std)
    new_v = xp.matmul(batch["obs"], params["wv"])[:, 0]
    entropy = distributions.gaussian_entropy(log_std)
    return ppo.ppo_loss(new_lp, batch["old_lp"], batch["adv"], new_v, batch["old_v"], batch["returns"],
                        entropy, clip_eps=0.2, value_clip=0.2, vf_coef=1.0, ent_coef=0.01)


def _sac_params_and_batch():
    rng = np.random.default_rng(1)
    params = {
        "actor": {"w": rng.normal(size=(D, A)) * 0.5, "log_std": rng.uniform(-1.0, 0.0, A)},
        "critic": {"w1": rng.normal(size=(D + A, 16)) * 0.4, "w2": rng.normal(size=(16, 2)) * 0.4},
        "log_alpha": np.asarray(-1.0),
    }
    batch = {"obs": rng.normal(size=(N, D)), "actions": np.tanh(rng.normal(size=(N, A))),
             "eps": rng.normal(size=(N, A)), "target": rng.normal(size=N)}
    return f32_tree(params), f32_tree(batch)


def _twin_q(xp, critic, obs, act):
    h = xp.tanh(xp.matmul(xp.concat([obs, act], axis=-1), critic["w1"]))
    q = xp.matmul(h, critic["w2"])
    return q[:, 0], q[:, 1]


def _sac_objective(params, batch):
    xp = shim.namespace(params["actor"]["w"])
    q1, q2 = _twin_q(xp, params["critic"], batch["obs"], batch["actions"])
    critic_loss = sac.sac_critic_loss(q1, q2, batch["target"])
    mean = xp.matmul(batch["obs"], params["actor"]["w"])
    action, log_prob = distributions.tanh_gaussian_sample(mean, params["actor"]["log_std"], batch["eps"])
    critic_frozen = xp.tree_map(xp.stop_gradient, params["critic"])
    pq1, pq2 = _twin_q(xp, critic_frozen, batch["obs"], action)
    alpha = xp.exp(params["log_alpha"])
    actor_loss = sac.sac_actor_loss(pq1, pq2, log_prob, alpha)
    temp_loss = sac.sac_temperature_loss(params["log_alpha"], log_prob, -float(A))
    total = critic_loss + actor_loss + temp_loss
    return total, {"critic": critic_loss, "actor": actor_loss, "temperature": temp_loss}


def _c51_objective(params, batch):
    xp = shim.namespace(params["w"])
    logits = xp.matmul(batch["obs"], params["w"])
    # Both projections (dense and uniform-support) in one compiled objective.
    target = 0.5 * (c51.categorical_projection(batch["atoms"], batch["next_probs"], batch["rewards"],
                                               batch["discounts"])
                    + c51.categorical_projection_uniform(batch["next_probs"], batch["rewards"], batch["discounts"],
                                                         v_min=-3.0, v_max=3.0))
    mean = xp.mean(c51.categorical_mean(logits, batch["atoms"]))
    return c51.categorical_critic_loss(logits, target), {"mean": mean}


def _c51_params_and_batch():
    rng = np.random.default_rng(2)
    params = {"w": rng.normal(size=(D, K)) * 0.5}
    batch = {"obs": rng.normal(size=(N, D)), "atoms": np.linspace(-3.0, 3.0, K),
             "next_probs": rng.dirichlet(np.ones(K), size=N), "rewards": rng.normal(size=N),
             "discounts": np.full(N, 0.9)}
    return f32_tree(params), f32_tree(batch)


@pytest.mark.parametrize("objective, make", [(_ppo_objective, _ppo_params_and_batch),
                                             (_sac_objective, _sac_params_and_batch),
                                             (_c51_objective, _c51_params_and_batch)],
                         ids=["ppo", "sac", "c51"])
def test_gradients_match_between_jax_and_mlx(objective, make):
    params, batch = make()
    results = {}
    for name in ("jax", "mlx"):
        b = shim.get(name)
        fn = b.jit(b.value_and_grad(objective, has_aux=True))  # compiled on both (jax.jit / mx.compile)
        (loss, aux), grads = fn(put(b, params), put(b, batch))
        results[name] = to_np((loss, aux, grads))
    jax_res, mlx_res = results["jax"], results["mlx"]
    assert_close(mlx_res, jax_res, rtol=1e-5, atol=1e-5)
    # Every parameter receives a non-trivial gradient (so the comparison is not vacuous).
    for g in shim.tree_leaves(jax_res[2]):
        assert np.all(np.isfinite(g)) and np.abs(g).max() > 1e-6


def test_ppo_gradient_wrt_inputs_matches_finite_differences():
    # jax's autodiff through ppo_loss equals a float64 numpy finite difference of the same kernel.
    jx = shim.get("jax")
    rng = np.random.default_rng(3)
    old = rng.normal(size=16) - 1.0
    inputs = [old + rng.normal(size=16) * 0.1, old, rng.normal(size=16), rng.normal(size=16),
              rng.normal(size=16), rng.normal(size=16), rng.uniform(0.5, 1.5, 16)]
    kw = dict(clip_eps=0.2, value_clip=0.3, vf_coef=0.7, ent_coef=0.05)

    def loss_of(new_lp, new_v, ent, xs):
        return ppo.ppo_loss(new_lp, xs[1], xs[2], new_v, xs[4], xs[5], ent, **kw)[0]

    xs32 = [jx.from_numpy(f32(a)) for a in inputs]
    _, grads = jx.value_and_grad(lambda d: loss_of(d[0], d[1], d[2], xs32))((xs32[0], xs32[3], xs32[6]))
    h = 1e-6
    for gi, idx in zip(grads, (0, 3, 6)):
        fd = np.zeros(16)
        for i in range(16):
            up, dn = [np.array(a, np.float64) for a in inputs], [np.array(a, np.float64) for a in inputs]
            up[idx][i] += h
            dn[idx][i] -= h
            diff = float(loss_of(up[0], up[3], up[6], up)) - float(loss_of(dn[0], dn[3], dn[6], dn))
            fd[i] = diff / (2 * h)
        np.testing.assert_allclose(np.asarray(gi), fd, rtol=1e-4, atol=1e-5)
