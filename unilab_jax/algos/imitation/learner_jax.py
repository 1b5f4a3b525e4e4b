"""Behaviour cloning fitted with JAX: ``fit(dataset, config, seed) -> (weights, metrics)``.

A fit (each network of an ensemble alike) starts from fresh parameters with the dataset's observation
statistics, or from ``init`` (earlier weights, fine-tuned: their parameters and their observation statistics,
so the policy they were is where the fit starts), with a fresh optimizer, and runs ``epochs`` shuffled passes
of AdamW minibatch steps (or enough passes for ``steps`` gradient steps), each one ``jax.jit`` (``lax.scan``
over the minibatches of an epoch; the dataset is padded to whole minibatches by repeating shuffled rows).
Weights come back as numpy (``bc.act`` runs them anywhere).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.algos.imitation import bc
from unilab_jax.core import normalizer

NP = shim.get("numpy")


@functools.partial(jax.jit, static_argnames=("tx", "n_batches"))
def _epoch(params: Any, opt_state: Any, obs_norm: Any, obs: jax.Array, action: jax.Array, perm: jax.Array,
           tx: optax.GradientTransformation, n_batches: int) -> tuple[Any, Any, jax.Array]:
    idx = perm.reshape(n_batches, -1)

    def step(carry, rows):
        p, s = carry
        value, grads = jax.value_and_grad(bc.loss)(p, obs_norm, obs[rows], action[rows])
        updates, s = tx.update(grads, s, p)
        return (optax.apply_updates(p, updates), s), value

    (params, opt_state), losses = jax.lax.scan(step, (params, opt_state), idx)
    return params, opt_state, jnp.mean(losses)


@functools.cache
def _adamw(learning_rate: float, weight_decay: float) -> optax.GradientTransformation:
    """One optimizer object per setting, so the jitted epoch (static in it) compiles once per shape."""
    return optax.adamw(learning_rate, weight_decay=weight_decay)


MEMBER_SEED_STRIDE = 100_003  # ensemble member i fits with seed + i * this (member 0: the fit's seed)


def _fit_member(obs: np.ndarray, action: np.ndarray, config: bc.BCConfig, seed: int, stats: Any,
                actor: Any) -> tuple[Any, float, int]:
    """One network: (actor as numpy, last epoch's loss, gradient steps); ``actor`` None: fresh parameters."""
    rng = np.random.default_rng(seed)
    if actor is None:
        actor = bc.init_params(NP.random.key(seed), obs.shape[1], action.shape[1], config, NP)
    params = nets.convert(actor, shim.get("jax"))
    tx = _adamw(config.learning_rate, config.weight_decay)
    opt_state = tx.init(params)
    b = min(config.batch_size, len(obs))
    n_batches = -(-len(obs) // b)
    obs_norm = nets.convert(stats, shim.get("jax"))
    obs_j, action_j = jnp.asarray(obs), jnp.asarray(action)
    value = jnp.zeros(())
    epochs = config.epochs if config.steps is None else -(-config.steps // n_batches)
    for _ in range(epochs):
        perm = np.concatenate([rng.permutation(len(obs)), rng.integers(0, len(obs), n_batches * b - len(obs))])
        params, opt_state, value = _epoch(params, opt_state, obs_norm, obs_j, action_j, jnp.asarray(perm), tx,
                                          n_batches)
    return nets.to_numpy(params), float(value), epochs * n_batches


def fit(obs: np.ndarray, action: np.ndarray, config: bc.BCConfig, seed: int = 0,
        init: dict | None = None) -> tuple[dict, dict]:
    """obs [N, D], action [N, A] -> (weights as numpy, {"loss", "rows", "steps"}): ``{"actor", "obs_norm"}``, or
    with ``config.ensemble`` > 1 ``{"actors", "obs_norm"}`` (loss: the members' mean; steps: per member);
    ``init``: weights of the same shape to fine-tune (``fit``'s), else fresh parameters."""
    obs, action = np.asarray(obs, np.float32), np.asarray(action, np.float32)
    if obs.ndim != 2 or action.ndim != 2 or len(obs) != len(action) or len(obs) == 0:
        raise ValueError(f"fit needs obs [N, D] and action [N, A] with N > 0, got {obs.shape} and {action.shape}")
    key = "actors" if config.ensemble > 1 else "actor"
    if init is not None and (key not in init or (key == "actors" and len(init[key]) != config.ensemble)):
        raise ValueError(f"fit: init must be weights of a {config.ensemble}-network fit, got keys {sorted(init)}")
    if init is None:
        stats = normalizer.stats_update(normalizer.stats_init(obs.shape[1], NP), obs)
        inits = [None] * config.ensemble
    else:
        stats = init["obs_norm"]
        inits = init["actors"] if key == "actors" else [init["actor"]]
    members = [_fit_member(obs, action, config, seed + i * MEMBER_SEED_STRIDE, stats, actor)
               for i, actor in enumerate(inits)]
    actors = [m[0] for m in members]
    weights = {key: actors if key == "actors" else actors[0], "obs_norm": stats}
    return weights, {"loss": float(np.mean([m[1] for m in members])), "rows": len(obs), "steps": members[0][2]}
