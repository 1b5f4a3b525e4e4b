"""The device mirror of the replay rings: the rows it samples are exactly the rings' intact rows, even
with a writer racing the copies."""

from __future__ import annotations

import time

import numpy as np
import pytest
import rt_helpers
from rt_helpers import replay_rows_ok, replay_value, replay_worker_and_index, write_replay_step

from unilab_jax.runtime.buffers import ReplayBuffer

jax = pytest.importorskip("jax")
from unilab_jax.training.device_replay import DeviceReplay  # noqa: E402

pytestmark = pytest.mark.timeout(120)

FIELDS = rt_helpers.PATTERN_FIELDS


def _gathered(mirror: DeviceReplay, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {k: np.asarray(v) for k, v in mirror.sample((n,), rng).items()}


def test_mirror_samples_the_valid_rows_uniformly_across_syncs_and_laps():
    buf = ReplayBuffer.create(FIELDS, num_workers=3, envs_per_worker=4, capacity=16)
    try:
        mirror = DeviceReplay(buf, FIELDS)
        with pytest.raises(ValueError, match="empty"):
            mirror.sample((1,), np.random.default_rng(0))
        assert mirror.sync() == 0
        for worker, steps in enumerate((1, 2, 3)):
            for _ in range(steps):
                write_replay_step(buf, worker)
        assert mirror.sync() == 24 and mirror.size == 24
        # Worker 0 laps its ring twice between two syncs (rows 4-35 written, only 24-35 survive),
        # worker 1 adds one step, worker 2 none.
        for _ in range(8):
            write_replay_step(buf, 0)
        write_replay_step(buf, 1)
        mirror.sync()
        # Valid as host sampling defines it: committed and not the oldest step of a full region.
        valid = np.concatenate([replay_value(0, np.arange(24, 36)), replay_value(1, np.arange(0, 12)),
                                replay_value(2, np.arange(0, 12))])
        assert mirror.size == valid.size
        n = 48_000
        batch = _gathered(mirror, n, np.random.default_rng(3))
        assert replay_rows_ok(batch).all()
        values, counts = np.unique(batch["b"], return_counts=True)
        np.testing.assert_array_equal(values, np.sort(valid))
        expect = n / valid.size
        assert np.abs(counts - expect).max() < 5 * np.sqrt(expect)
        # Same generator state, same draw.
        again = _gathered(mirror, n, np.random.default_rng(3))
        np.testing.assert_array_equal(again["b"], batch["b"])
        # Field shapes are the rings'; dtypes too, as JAX holds them (int64 -> int32 without x64).
        for name, (shape, dtype) in FIELDS.items():
            assert batch[name].shape == (n, *shape)
            assert batch[name].dtype == jax.dtypes.canonicalize_dtype(dtype)
    finally:
        buf.close()


def test_uploads_are_padded_to_few_sizes():
    buf = ReplayBuffer.create(FIELDS, num_workers=1, envs_per_worker=4, capacity=4096)
    try:
        mirror = DeviceReplay(buf, FIELDS)
        for steps in (1, 3, 5, 300):
            for _ in range(steps):
                write_replay_step(buf, 0)
            mirror.sync()
        assert mirror.uploaded == 4 * 309
        batch = _gathered(mirror, 4096, np.random.default_rng(0))
        assert replay_rows_ok(batch).all() and set(np.unique(batch["b"])) <= set(replay_value(0, np.arange(4 * 309)))
    finally:
        buf.close()


def test_mirror_races_a_writer_process():
    """A process laps a small ring while the mirror syncs and samples: no gathered row is ever torn and
    every row drawn is among the newest ``capacity`` rows at the time of the sync."""
    buf = ReplayBuffer.create(FIELDS, num_workers=2, envs_per_worker=8, capacity=32)
    try:
        for _ in range(4):
            write_replay_step(buf, 1)
        with rt_helpers.racing_replay_writer(buf, 0):
            mirror = DeviceReplay(buf, FIELDS)
            rng = np.random.default_rng(4)
            torn = calls = 0
            t_end = time.monotonic() + 10
            while calls < 200 and time.monotonic() < t_end:
                mirror.sync()
                hi = mirror.hi.copy()
                batch = _gathered(mirror, 512, rng)
                torn += int((~replay_rows_ok(batch)).sum())
                worker, index = replay_worker_and_index(batch["b"])
                assert (index < hi[worker]).all() and (index >= hi[worker] - buf.capacity).all()
                calls += 1
        assert calls >= 20 and torn == 0, f"{torn} torn rows in {calls} batches"
    finally:
        buf.close()
