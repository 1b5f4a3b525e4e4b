"""Checkpoints written by an earlier version still restore, bitwise, through the ``--resume`` path.

``tests/fixtures/checkpoints/<algo>/`` holds the checkpoint folder of a tiny cart-pole run made with
the trainer at commit 516a2d2 (before the layered package layout), e.g. for PPO::

    python experiments/ppo_cartpole.py --serial --num_workers=1 --envs_per_worker=4 --total_steps=256 \
        --seed=3 --eval_envs=2 --config actor_hidden=8,8 --config critic_hidden=8,8 --config horizon=16 \
        --config num_minibatches=2 --config num_epochs=2

(SAC and TD3: ``--total_steps=512`` with ``batch_size=16 updates_per_call=2 publish_every=2
learning_starts=128 utd=0.05 replay_capacity=1024``), and ``<algo>.npz`` every leaf of the state that
commit restored from it, keyed by its path. A restore today must give the same tree, leaf for leaf.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import shutil

import numpy as np
import pytest

from unilab_jax import algos
from unilab_jax import xp as shim
from unilab_jax.config import apply_overrides
from unilab_jax.training.trainer import RunConfig, Trainer

FIXTURES = pathlib.Path(__file__).parent / "fixtures" / "checkpoints"


def restore(algo: str, logdir: pathlib.Path):
    """The state ``--resume`` restores from ``logdir`` (a copy of the fixture) and its counters."""
    shutil.copytree(FIXTURES / algo, logdir / "checkpoints")
    meta_run = {f.name for f in dataclasses.fields(RunConfig)}
    step = sorted((logdir / "checkpoints").iterdir())[0]
    meta = json.loads((step / "meta" / "metadata").read_text())
    run = RunConfig(**{**{k: v for k, v in meta["run"].items() if k in meta_run}, "logdir": str(logdir),
                       "resume": True})
    module = algos.get(algo)
    trainer = Trainer(run, module, apply_overrides(module.Config(), meta["config"]), {})
    state, counters = trainer._init_state()
    trainer.logger.close()
    return state, counters, meta


@pytest.mark.parametrize("algo", ["ppo", "sac", "td3"])
def test_old_checkpoint_restores_bitwise(algo, tmp_path):
    state, counters, meta = restore(algo, tmp_path)
    assert counters == meta["counters"]
    expected = np.load(FIXTURES / f"{algo}.npz")
    leaves = dict(shim.tree_paths(state))
    assert sorted(leaves) == sorted(expected.files)
    for path, leaf in leaves.items():
        a, b = np.asarray(leaf), expected[path]
        assert a.dtype == b.dtype and a.shape == b.shape, path
        assert a.tobytes() == b.tobytes(), path
