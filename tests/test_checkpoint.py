"""Orbax checkpoints of the whole training state: exact round trip, named mismatches."""

import jax
import numpy as np
import pytest
from ckpt_helpers import to_jax as _to_jax
from ckpt_helpers import train_state as _state

from unilab_jax.checkpoint import Checkpointer, CheckpointMismatchError


def test_round_trip_is_bitwise(tmp_path):
    state = _state([3, 8, 2])
    ck = Checkpointer(str(tmp_path / "ck"))
    ck.save(10, state, {"counters": {"env_steps": 10}})
    ck.wait()
    template = _state([3, 8, 2], seed=1)
    restored, meta = ck.restore(template, _to_jax)
    ck.close()
    assert meta["counters"]["env_steps"] == 10
    assert jax.tree_util.tree_structure(restored) == jax.tree_util.tree_structure(state)
    for a, b in zip(jax.tree_util.tree_leaves(state), jax.tree_util.tree_leaves(restored)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        assert np.asarray(a).dtype == np.asarray(b).dtype


def test_mismatched_network_names_the_leaf(tmp_path):
    ck = Checkpointer(str(tmp_path / "ck"))
    ck.save(1, _state([3, 8, 2]), {})
    ck.wait()
    with pytest.raises(CheckpointMismatchError, match=r"params/0/w: checkpoint \(3, 8\) vs state \(3, 16\)"):
        ck.restore(_state([3, 16, 2]), _to_jax)
    with pytest.raises(CheckpointMismatchError, match=r"missing from the checkpoint: \[[^]]*'params/2/b'"):
        ck.restore(_state([3, 8, 4, 2]), _to_jax)
    ck.close()


def test_keeps_latest_and_errors_when_empty(tmp_path):
    ck = Checkpointer(str(tmp_path / "ck"), max_to_keep=2)
    with pytest.raises(FileNotFoundError):
        ck.restore(_state([2, 2]), _to_jax)
    for step in (1, 2, 3):
        ck.save(step, _state([2, 2], seed=step), {"step": step})
    ck.wait()
    assert ck.latest_step() == 3
    _, meta = ck.restore(_state([2, 2]), _to_jax)
    assert meta["step"] == 3
    ck.close()


def test_saving_an_existing_step_replaces_it(tmp_path):
    # The trainer's final save can land on the step of an evaluation checkpoint, with newer state.
    ck = Checkpointer(str(tmp_path / "ck"))
    ck.save(5, _state([2, 2], seed=1), {"v": 1})
    newer = _state([2, 2], seed=2)
    ck.save(5, newer, {"v": 2})
    ck.wait()
    restored, meta = ck.restore(_state([2, 2]), _to_jax)
    ck.close()
    assert meta["v"] == 2
    np.testing.assert_array_equal(np.asarray(restored["params"][0]["w"]), np.asarray(newer["params"][0]["w"]))
