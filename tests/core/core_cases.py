"""Every kernel with a generator of random numpy inputs: shared by the parity, jit and strict tests.

A case is ``Case(name, fn, make)`` where ``make(rng)`` returns ``(arrays, static)``: ``arrays`` is a
tuple of numpy arrays (or pytrees of them; bool arrays are flags) passed positionally and ``static``
are python keyword arguments. ``fn(*arrays, **static)`` returns an array or a pytree of arrays.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from unilab_jax import nets_temporal
from unilab_jax.core import adaptation as hora
from unilab_jax.core import c51, distributions, gae, him, normalizer, polyak, vtrace
from unilab_jax.core import ppo_losses as ppo
from unilab_jax.core import sac_losses as sac
from unilab_jax.core import td3_losses as td3

T, B, A, K, D = 12, 8, 4, 21, 5


class Case(NamedTuple):
    name: str
    fn: Callable[..., Any]
    make: Callable[[np.random.Generator], tuple[tuple, dict]]


def _n(rng, *shape, scale=1.0, loc=0.0):
    return np.asarray(rng.normal(size=shape) * scale + loc)


def _gauss(rng):
    return _n(rng, B, A, scale=0.5), rng.uniform(-1.5, 0.5, size=(B, A))


def _rollout(rng):
    term = rng.random((T, B)) < 0.1
    trunc = (rng.random((T, B)) < 0.1) & ~term
    return _n(rng, T, B), _n(rng, T, B), _n(rng, T, B), term, trunc


def _ppo_batch(rng, n=64):
    old = _n(rng, n, loc=-2.0)
    return (old + _n(rng, n, scale=0.3), old, _n(rng, n, scale=2.0), _n(rng, n), _n(rng, n), _n(rng, n),
            rng.uniform(0.5, 2.0, size=n))


def _vtrace_inputs(rng):
    r, v, nv, term, trunc = _rollout(rng)
    return v, nv, r, 0.97 * (1.0 - term), _n(rng, T, B, scale=0.6), term | trunc


def _stats(rng):
    s = normalizer.RunningStats(_n(rng, D), rng.uniform(0.5, 2.0, D), np.asarray(100.0))
    return s, _n(rng, 37, D, scale=2.0, loc=1.0)


def _normalizer_pipeline(stats, batch, other_batch):
    merged = normalizer.stats_merge(normalizer.stats_update(stats, batch),
                                    normalizer.stats_update(stats, other_batch))
    return merged, normalizer.normalize(merged, batch, clip=2.0)


def _polyak_trees(rng):
    mk = lambda: {"q": [{"w": _n(rng, D, 8), "b": _n(rng, 8)}, {"w": _n(rng, 8, 1), "b": _n(rng, 1)}],
                  "log_alpha": _n(rng)}
    return mk(), mk()


def _c51_inputs(rng):
    probs = rng.dirichlet(np.ones(K) * 0.5, size=B)
    return np.linspace(-5.0, 5.0, K), probs, _n(rng, B, scale=2.0), np.where(rng.random(B) < 0.2, 0.0, 0.99)


def _unit(rng, *shape):
    x = rng.normal(size=shape)
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _conv_params(rng, k, c_in, c_out):
    return {"w": _n(rng, k, c_in, c_out, scale=0.4), "b": _n(rng, c_out, scale=0.1)}


def _adaptation_inputs(rng, frames=16, d=D):
    params = {"embed": [{"w": _n(rng, d, 8, scale=0.4), "b": _n(rng, 8, scale=0.1)}],
              "convs": [_conv_params(rng, 4, 8, 6), _conv_params(rng, 3, 6, 6)],
              "proj": [{"w": _n(rng, 6 * 5, 3, scale=0.3), "b": _n(rng, 3, scale=0.1)}]}
    return params, _n(rng, B, frames, d)


CASES = [
    Case("gaussian_log_prob", distributions.gaussian_log_prob, lambda r: ((_n(r, B, A), *_gauss(r)), {})),
    Case("gaussian_entropy", distributions.gaussian_entropy, lambda r: ((_gauss(r)[1],), {})),
    Case("gaussian_kl", distributions.gaussian_kl, lambda r: ((*_gauss(r), *_gauss(r)), {})),
    Case("tanh_gaussian_sample", distributions.tanh_gaussian_sample,
         lambda r: ((*_gauss(r), _n(r, B, A)), {})),
    Case("tanh_gaussian_log_prob", distributions.tanh_gaussian_log_prob,
         lambda r: ((_n(r, B, A, scale=2.0), *_gauss(r)), {})),
    Case("tanh_gaussian_entropy_estimate", distributions.tanh_gaussian_entropy_estimate,
         lambda r: ((*_gauss(r), _n(r, B, A)), {})),
    Case("gae", gae.gae, lambda r: (_rollout(r), {"gamma": 0.99, "lam": 0.95})),
    Case("ppo_loss", ppo.ppo_loss,
         lambda r: (_ppo_batch(r), {"clip_eps": 0.2, "value_clip": 0.2, "vf_coef": 1.0, "ent_coef": 0.01})),
    Case("ppo_loss_plain", ppo.ppo_loss,
         lambda r: (_ppo_batch(r), {"clip_eps": 0.1, "value_clip": None, "vf_coef": 0.5, "ent_coef": 0.0,
                                    "normalize_advantages": False})),
    Case("kl_adaptive_lr", ppo.kl_adaptive_lr,
         lambda r: ((np.asarray(1e-3), np.asarray(r.choice([0.001, 0.01, 0.05]))), {"desired_kl": 0.01})),
    Case("vtrace", vtrace.vtrace,
         lambda r: (_vtrace_inputs(r), {"lam": 0.95, "clip_rho": 1.0, "clip_pg_rho": 1.0})),
    Case("appo_loss", vtrace.appo_loss,
         lambda r: (_ppo_batch(r)[:4] + (_n(r, 64), r.uniform(0.5, 2.0, 64)),
                    {"clip_eps": 0.2, "vf_coef": 0.5, "ent_coef": 0.01})),
    Case("sac_target", sac.sac_target,
         lambda r: ((_n(r, B), np.full(B, 0.99), _n(r, B), _n(r, B), _n(r, B), np.asarray(0.1)), {})),
    Case("sac_critic_loss", sac.sac_critic_loss, lambda r: ((_n(r, B), _n(r, B), _n(r, B)), {})),
    Case("sac_actor_loss", sac.sac_actor_loss,
         lambda r: ((_n(r, B), _n(r, B), _n(r, B), np.asarray(0.2)), {})),
    Case("sac_temperature_loss", sac.sac_temperature_loss,
         lambda r: ((np.asarray(-1.2), _n(r, B)), {"target_entropy": -float(A)})),
    Case("td3_target_action", td3.td3_target_action,
         lambda r: ((np.tanh(_n(r, B, A)), _n(r, B, A, scale=0.4)), {"noise_clip": 0.5})),
    Case("td3_target", td3.td3_target, lambda r: ((_n(r, B), np.full(B, 0.99), _n(r, B), _n(r, B)), {})),
    Case("td3_critic_loss", td3.td3_critic_loss, lambda r: ((_n(r, B), _n(r, B), _n(r, B)), {})),
    Case("td3_actor_loss", td3.td3_actor_loss, lambda r: ((_n(r, B),), {})),
    Case("categorical_projection", c51.categorical_projection, lambda r: (_c51_inputs(r), {})),
    Case("categorical_projection_uniform", c51.categorical_projection_uniform,
         lambda r: (_c51_inputs(r)[1:], {"v_min": -5.0, "v_max": 5.0})),
    Case("categorical_critic_loss", c51.categorical_critic_loss,
         lambda r: ((_n(r, B, K), r.dirichlet(np.ones(K), size=B)), {})),
    Case("categorical_mean", c51.categorical_mean, lambda r: ((_n(r, B, K), np.linspace(-5.0, 5.0, K)), {})),
    Case("normalizer", _normalizer_pipeline, lambda r: ((*_stats(r), _n(r, 11, D)), {})),
    Case("polyak", polyak.polyak, lambda r: (_polyak_trees(r), {"tau": 0.005})),
    Case("l2_normalize", him.l2_normalize, lambda r: ((_n(r, B, A, scale=3.0),), {})),
    Case("sinkhorn", him.sinkhorn, lambda r: ((_unit(r, 16, A) @ _unit(r, 6, A).T,), {"n_iters": 3, "eps": 0.05})),
    Case("sinkhorn_many_iters", him.sinkhorn,
         lambda r: ((_n(r, 10, 5, scale=0.5),), {"n_iters": 10, "eps": 0.5})),
    Case("swapped_prediction_loss", him.swapped_prediction_loss,
         lambda r: ((_unit(r, 16, A), _unit(r, 16, A), _unit(r, 6, A)), {"temperature": 3.0})),
    Case("velocity_loss", him.velocity_loss, lambda r: ((_n(r, B, 3), _n(r, B, 3)), {})),
    Case("adaptation_loss", hora.adaptation_loss, lambda r: ((np.tanh(_n(r, B, A)), np.tanh(_n(r, B, A))), {})),
    Case("conv1d", nets_temporal.conv1d, lambda r: ((_conv_params(r, 4, 3, 5), _n(r, B, 11, 3)), {"stride": 2})),
    Case("adaptation_module", nets_temporal.adaptation_apply, lambda r: (_adaptation_inputs(r), {})),
]
CASE_IDS = [c.name for c in CASES]
