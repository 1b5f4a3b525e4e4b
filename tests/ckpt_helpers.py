"""A small training-state pytree (MLP params, Adam state after one step, RNG key, counter) for the
checkpoint tests."""

import jax
import jax.numpy as jnp
import optax

from unilab_jax import nets
from unilab_jax import xp as shim


def train_state(sizes, seed=0):
    xp = shim.get("jax")
    params = nets.init(xp.random.key(seed), sizes)
    tx = optax.chain(optax.clip_by_global_norm(1.0), optax.inject_hyperparams(optax.adam)(learning_rate=1e-3))
    opt = tx.init(params)
    grads = jax.tree_util.tree_map(jnp.ones_like, params)
    _, opt = tx.update(grads, opt, params)
    return {"params": params, "opt": opt, "key": jax.random.PRNGKey(seed), "count": jnp.int32(7)}


def to_jax(a, like):
    return jnp.asarray(a, dtype=like.dtype)
