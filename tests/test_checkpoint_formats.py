"""The numpy-only checkpoint format (MLX-only installs) and restores across formats.

``Checkpointer(format="npz")`` / ``UNILAB_CHECKPOINT_FORMAT=npz`` force the fallback that an install
without orbax (which needs jax) uses; ``restore`` reads whichever format each step folder holds.
"""

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from ckpt_helpers import to_jax as _to_jax
from ckpt_helpers import train_state

from unilab_jax.checkpoint import FORMAT_ENV, Checkpointer, CheckpointMismatchError


def _state(sizes, seed=0):
    return {**train_state(sizes, seed), "half": jnp.arange(5, dtype=jnp.bfloat16) / 3,
            "flags": jnp.array([True, False])}


def _assert_same(a, b):
    assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b)
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype and x.shape == y.shape
        assert x.tobytes() == y.tobytes()  # bitwise, NaN payloads included


def test_npz_round_trip_is_bitwise(tmp_path):
    state = _state([3, 8, 2])
    ck = Checkpointer(str(tmp_path / "ck"), format="npz")
    assert ck.format == "npz"
    ck.save(10, state, {"counters": {"env_steps": 10}})
    ck.wait()
    assert ck.latest_step() == 10 and ck.step_format(10) == "npz"
    assert sorted(os.listdir(tmp_path / "ck" / "10")) == ["meta.json", "state.npz", "unilab_checkpoint.json",
                                                        "unilab_digests.json"]
    restored, meta = ck.restore(_state([3, 8, 2], seed=1), _to_jax)
    ck.close()
    assert meta == {"counters": {"env_steps": 10}}
    _assert_same(state, restored)


def test_env_var_forces_npz(tmp_path, monkeypatch):
    monkeypatch.setenv(FORMAT_ENV, "npz")
    assert Checkpointer(str(tmp_path / "a")).format == "npz"
    monkeypatch.setenv(FORMAT_ENV, "orbax")
    assert Checkpointer(str(tmp_path / "b")).format == "orbax"
    monkeypatch.setenv(FORMAT_ENV, "pickle")
    with pytest.raises(ValueError, match="pickle"):
        Checkpointer(str(tmp_path / "c"))


def test_npz_mismatched_network_names_the_leaf(tmp_path):
    ck = Checkpointer(str(tmp_path / "ck"), format="npz")
    ck.save(1, _state([3, 8, 2]), {})
    with pytest.raises(CheckpointMismatchError, match=r"params/0/w: checkpoint \(3, 8\) vs state \(3, 16\)"):
        ck.restore(_state([3, 16, 2]), _to_jax)
    with pytest.raises(CheckpointMismatchError, match=r"missing from the checkpoint: \[[^]]*'params/2/b'"):
        ck.restore(_state([3, 8, 4, 2]), _to_jax)
    small = _state([3, 8, 2])
    del small["count"]
    with pytest.raises(CheckpointMismatchError, match=r"in the checkpoint but not in the state: \['count'\]"):
        ck.restore(small, _to_jax)


@pytest.mark.parametrize("writer,reader", [("npz", "orbax"), ("orbax", "npz")])
def test_cross_format_restore(tmp_path, writer, reader):
    state = _state([4, 8, 2])
    w = Checkpointer(str(tmp_path / "ck"), format=writer)
    w.save(5, state, {"written_by": writer})
    w.close()
    r = Checkpointer(str(tmp_path / "ck"), format=reader)
    assert r.latest_step() == 5 and r.step_format(5) == writer
    restored, meta = r.restore(_state([4, 8, 2], seed=3), _to_jax)
    assert meta == {"written_by": writer}
    _assert_same(state, restored)
    # The reader appends its own format after the writer's; both steps restore, the latest is the reader's.
    r.save(6, _state([4, 8, 2], seed=6), {"written_by": reader})
    r.wait()
    assert r.all_steps() == [5, 6] and r.step_format(6) == reader
    _, meta = r.restore(_state([4, 8, 2]), _to_jax)
    assert meta == {"written_by": reader}
    _, meta = r.restore(_state([4, 8, 2]), _to_jax, step=5)
    assert meta == {"written_by": writer}
    r.close()


def test_only_restores_named_subtrees(tmp_path):
    state = _state([3, 8, 2])
    ck = Checkpointer(str(tmp_path / "ck"), format="npz")
    ck.save(1, state, {})
    out, _ = ck.restore({"params": _state([3, 8, 2], seed=2)["params"]}, _to_jax, only=("params",))
    _assert_same({"params": state["params"]}, out)


def test_npz_keeps_latest_and_ignores_incomplete_temp_dirs(tmp_path):
    root = tmp_path / "ck"
    ck = Checkpointer(str(root), max_to_keep=2, format="npz")
    with pytest.raises(FileNotFoundError):
        ck.restore(_state([2, 2]), _to_jax)
    for step in (1, 2, 3):
        ck.save(step, _state([2, 2], seed=step), {"step": step})
    assert ck.all_steps() == [2, 3]
    assert sorted(os.listdir(root)) == ["2", "3"]
    # A save that crashed half-way (no rename): a temp folder of a live process (this one) and of a dead one.
    live = root / f"9.unilab-tmp-{os.getpid()}-deadbeef"
    live.mkdir()
    (live / "state.npz").write_bytes(b"PK truncated")
    dead = root / "8.unilab-tmp-999999999-cafef00d"
    dead.mkdir()
    assert ck.latest_step() == 3
    _, meta = ck.restore(_state([2, 2]), _to_jax)
    assert meta == {"step": 3}
    ck2 = Checkpointer(str(root), max_to_keep=2, format="npz")  # opening cleans up only the dead one
    assert ck2.latest_step() == 3 and live.exists() and not dead.exists()
    # Re-saving a step replaces it whole.
    ck2.save(3, _state([2, 2], seed=30), {"step": 30})
    assert ck2.all_steps() == [2, 3]
    _, meta = ck2.restore(_state([2, 2]), _to_jax)
    assert meta == {"step": 30}
    with open(root / "3" / "unilab_checkpoint.json") as f:
        assert json.load(f)["format"] == "npz"


def test_npz_meta_must_be_json_and_leaves_nothing_behind(tmp_path):
    ck = Checkpointer(str(tmp_path / "ck"), format="npz")
    with pytest.raises(TypeError):
        ck.save(1, _state([2, 2]), {"bad": object()})
    assert os.listdir(tmp_path / "ck") == [] and ck.latest_step() is None
