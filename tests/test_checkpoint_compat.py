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

import numpy as np
import pytest
from ckpt_helpers import FIXTURES
from ckpt_helpers import resume_fixture as restore

from unilab_jax import xp as shim


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
