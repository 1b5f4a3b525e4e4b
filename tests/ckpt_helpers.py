"""A small training-state pytree (MLP params, Adam state after one step, RNG key, counter) for the
checkpoint tests, and the ``--resume`` path over a copy of an old checkpoint (tests/fixtures/checkpoints)."""

import dataclasses
import json
import pathlib
import shutil

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


FIXTURES = pathlib.Path(__file__).parent / "fixtures" / "checkpoints"


def resume_fixture(algo, logdir, prepare=None):
    """(state, counters, meta) ``--resume`` restores from ``logdir`` holding a copy of the fixture of ``algo``;
    ``prepare(checkpoint_dir)`` runs on the copy first (to damage it, leave a temporary folder ...)."""
    from unilab_jax import algos
    from unilab_jax.config import apply_overrides
    from unilab_jax.training.trainer import RunConfig, Trainer

    shutil.copytree(FIXTURES / algo, logdir / "checkpoints")
    meta_run = {f.name for f in dataclasses.fields(RunConfig)}
    step = sorted((logdir / "checkpoints").iterdir())[0]
    meta = json.loads((step / "meta" / "metadata").read_text())
    if prepare is not None:
        prepare(logdir / "checkpoints")
    run = RunConfig(**{**{k: v for k, v in meta["run"].items() if k in meta_run}, "logdir": str(logdir),
                       "resume": True})
    module = algos.get(algo)
    trainer = Trainer(run, module, apply_overrides(module.Config(), meta["config"]), {})
    try:
        state, counters = trainer._init_state()
    finally:
        trainer.logger.close()
    return state, counters, meta
