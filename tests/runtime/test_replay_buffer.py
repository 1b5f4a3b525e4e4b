"""ReplayBuffer sampling: uniform draws in random order, the cursor seqlock against a racing writer."""

from __future__ import annotations

import time

import numpy as np
import pytest
import rt_helpers
from rt_helpers import replay_rows_ok, replay_value, replay_worker_and_index, write_replay_step

from unilab_jax.runtime.buffers import ReplayBuffer

pytestmark = pytest.mark.timeout(120)

FIELDS = rt_helpers.PATTERN_FIELDS  # float32 [64], int64, int32 [3], bool, float32 [17]; "b" holds the value


def test_capacity_is_whole_steps_and_at_least_two_and_empty_rings_refuse_to_sample():
    for capacity, want in ((3, 8), (8, 8), (9, 12)):
        buf = ReplayBuffer.create(FIELDS, num_workers=1, envs_per_worker=4, capacity=capacity)
        try:
            assert buf.capacity == want
            with pytest.raises(ValueError, match="empty"):
                buf.sample(1, np.random.default_rng(0))
        finally:
            buf.close()


def test_sample_is_uniform_over_the_valid_rows_and_in_random_order():
    buf = ReplayBuffer.create(FIELDS, num_workers=3, envs_per_worker=4, capacity=16)
    try:
        for worker, steps in enumerate((2, 4, 9)):  # not full; just full; wrapped twice
            for _ in range(steps):
                write_replay_step(buf, worker)
        # Valid: committed and not the oldest step of a full region (its writer's next).
        valid = np.concatenate([replay_value(0, np.arange(0, 8)), replay_value(1, np.arange(4, 16)),
                                replay_value(2, np.arange(24, 36))])
        n = 64_000
        batch = buf.sample(n, np.random.default_rng(7))
        assert replay_rows_ok(batch).all()
        values, counts = np.unique(batch["b"], return_counts=True)
        np.testing.assert_array_equal(values, np.sort(valid))
        expect = n / valid.size
        assert np.abs(counts - expect).max() < 5 * np.sqrt(expect)
        # Draw order, not grouped by worker: consecutive rows share a worker with probability sum(p_w^2).
        worker, _ = replay_worker_and_index(batch["b"])
        p = np.array([8, 12, 12]) / 32
        assert abs(np.mean(worker[1:] == worker[:-1]) - np.sum(p**2)) < 0.01
        assert buf.resampled == 0
        again = buf.sample(n, np.random.default_rng(7))
        np.testing.assert_array_equal(again["b"], batch["b"])
    finally:
        buf.close()


def test_the_step_being_written_is_never_drawn():
    """The rows at a full region's cursor are the writer's (mid-step, or left by a killed worker)."""
    buf = ReplayBuffer.create(FIELDS, num_workers=1, envs_per_worker=4, capacity=8)
    try:
        for _ in range(2):
            write_replay_step(buf, 0)
        _, views = buf.rows(0)  # step 3 started, not committed: it overwrites rows 0-3
        views["b"][...] = -1
        views["a"][...] = np.nan
        batch = buf.sample(1000, np.random.default_rng(0))
        assert replay_rows_ok(batch).all()
        np.testing.assert_array_equal(np.unique(batch["b"]), np.arange(4, 8))
        assert buf.resampled == 0  # not drawn and redrawn: not drawn at all
        write_replay_step(buf, 0)
        batch = buf.sample(1000, np.random.default_rng(0))
        np.testing.assert_array_equal(np.unique(batch["b"]), np.arange(8, 12))
    finally:
        buf.close()


class _WriterDuringCopy(dict):
    """The sampler's flat field views; the first read of ``trigger`` runs ``steps`` writer steps first,
    so the rows they overwrite are copied half before and half after the overwrite."""

    def __init__(self, flat: dict, buf: ReplayBuffer, trigger: str, steps: int):
        super().__init__(flat)
        self.buf, self.trigger, self.steps = buf, trigger, steps

    def __getitem__(self, name):
        if name == self.trigger and self.steps:
            for _ in range(self.steps):
                write_replay_step(self.buf, 0)
            self.steps = 0
        return super().__getitem__(name)


def test_rows_the_writer_reaches_during_the_copy_are_redrawn():
    buf = ReplayBuffer.create(FIELDS, num_workers=2, envs_per_worker=4, capacity=16)
    try:
        for _ in range(4):
            write_replay_step(buf, 0)
            write_replay_step(buf, 1)
        # Worker 0 commits 2 steps after field "a" was copied: rows 16-23 replace 0-7 (4-7 were drawable).
        buf._flat = _WriterDuringCopy(buf._flat, buf, trigger="b", steps=2)
        batch = buf.sample(4000, np.random.default_rng(1))
        assert buf._flat.steps == 0  # the writer did run mid-copy
        assert replay_rows_ok(batch).all()  # no torn row: a from the old lap, b from the new one
        worker, index = replay_worker_and_index(batch["b"])
        # Redrawn: every draw of worker 0 below c1 + M - C = 24 + 4 - 16, rows 4-11 (8 of 24 rows: ~1333).
        assert 1150 < buf.resampled < 1520
        assert set(index[worker == 0]) == set(range(12, 24))  # 12-15 kept, 16-23 from the redraw
        assert set(index[worker == 1]) == set(range(4, 16))
    finally:
        buf.close()


@pytest.mark.parametrize("capacity,batch", [(32, 256), (8192, 16384)], ids=["lapped-ring", "threaded-gather"])
def test_sampling_races_a_writer_process(capacity, batch):
    """A process writes a ring as fast as it can while the learner samples: no row is ever torn. A 4-step
    ring is lapped during most copies; 16,384-row batches are gathered by several threads (on 2+ cores)."""
    buf = ReplayBuffer.create(FIELDS, num_workers=2, envs_per_worker=8, capacity=capacity)
    try:
        for _ in range(4):
            write_replay_step(buf, 1)  # a still region beside the racing one
        with rt_helpers.racing_replay_writer(buf, 0):
            rng = np.random.default_rng(2)
            torn = calls = 0
            t_end = time.monotonic() + 15
            while (buf.resampled < 100 or calls < 100) and time.monotonic() < t_end:
                got = buf.sample(batch, rng)
                torn += int((~replay_rows_ok(got)).sum())
                calls += 1
        assert torn == 0, f"{torn} torn rows in {calls} batches"
        assert buf.resampled > 0, "the writer never overtook a copy: the race did not happen"
    finally:
        buf.close()
