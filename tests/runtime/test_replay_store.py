"""The persistent replay store: chunks, recovery after crashes and corruption, the disk budget, the
ring spiller and the tiered sampler. Rows carry their own global index (``idx``), so every read can
be checked against what was written."""

from __future__ import annotations

import json
import logging
import os
import random
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from unilab_jax.runtime.buffers import ReplayBuffer, row_checksums
from unilab_jax.runtime.replay_store import (
    ReplayStore,
    RingSpiller,
    StoreCorruptError,
    StoreFormatError,
    StoreLockedError,
    TieredSampler,
)

pytestmark = pytest.mark.timeout(120)

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
FIELDS = {"idx": ((), np.dtype(np.int64)), "obs": ((3,), np.dtype(np.float32)), "done": ((), np.dtype(bool))}


def _rows(start: int, n: int) -> dict[str, np.ndarray]:
    idx = np.arange(start, start + n, dtype=np.int64)
    return {"idx": idx, "obs": np.stack([idx, -idx, idx % 7], axis=1).astype(np.float32), "done": idx % 5 == 0}


def _check_rows(rows: dict[str, np.ndarray]) -> None:
    """Every field of every row agrees with its idx (no torn or mixed-up rows)."""
    idx = rows["idx"]
    np.testing.assert_array_equal(rows["obs"], np.stack([idx, -idx, idx % 7], axis=1).astype(np.float32))
    np.testing.assert_array_equal(rows["done"], idx % 5 == 0)


def _chunk_files(d) -> list[str]:
    return sorted(n for n in os.listdir(d) if n.startswith("chunk_"))


def test_chunks_commit_as_they_fill_and_sampling_reads_the_right_rows(tmp_path):
    store = ReplayStore(str(tmp_path), FIELDS, chunk_rows=100)
    for start, n in ((0, 30), (30, 170), (200, 1), (201, 349)):
        store.append(_rows(start, n))
    assert (store.committed, store.size, store.pending, store.num_chunks) == (500, 500, 50, 5)
    assert len(_chunk_files(tmp_path)) == 5
    got = store.read(0, 500)
    np.testing.assert_array_equal(got["idx"], np.arange(500))
    _check_rows(got)
    sample = store.sample(20_000, np.random.default_rng(0))
    _check_rows(sample)
    assert sample["idx"].min() >= 0 and sample["idx"].max() < 500  # staged rows are never sampled
    per_chunk = np.bincount(sample["idx"] // 100, minlength=5)
    assert per_chunk.min() > 3_600 and per_chunk.max() < 4_400  # uniform: 4000 each, sd ~57
    assert store.flush() == 550 and store.num_chunks == 6  # the staged rows as a short chunk
    np.testing.assert_array_equal(store.read(500, 550)["idx"], np.arange(500, 550))
    store.close()


def test_close_without_flush_loses_only_the_staged_rows(tmp_path):
    store = ReplayStore(str(tmp_path), FIELDS, chunk_rows=100)
    store.append(_rows(0, 250))
    store.close()
    store = ReplayStore(str(tmp_path), FIELDS, chunk_rows=100)
    assert (store.committed, store.size, store.pending) == (200, 200, 0)
    store.append(_rows(200, 100))
    np.testing.assert_array_equal(store.read(0, 300)["idx"], np.arange(300))
    store.close()


def test_recovery_removes_temp_files_and_orphans_and_drops_a_corrupt_chunk(tmp_path, caplog):
    d = str(tmp_path)
    store = ReplayStore(d, FIELDS, chunk_rows=100)
    store.append(_rows(0, 500))
    store.close()
    # What a crash can leave: a half-written chunk and index, a renamed chunk the index never listed.
    for name in ("chunk_000000005.npy.tmp", "index.json.tmp"):
        with open(os.path.join(d, name), "wb") as f:
            f.write(b"partial")
    os.link(os.path.join(d, "chunk_000000004.npy"), os.path.join(d, "chunk_000000005.npy"))
    # Bit rot in chunk 2 (its last byte: record data, not the .npy header), chunk 3 cut short.
    with open(os.path.join(d, "chunk_000000002.npy"), "r+b") as f:
        f.seek(-1, os.SEEK_END)
        byte = f.read(1)
        f.seek(-1, os.SEEK_END)
        f.write(bytes([byte[0] ^ 0x10]))
    with open(os.path.join(d, "chunk_000000003.npy"), "r+b") as f:
        f.truncate(os.path.getsize(f.name) - 24)
    with caplog.at_level(logging.WARNING, logger="unilab_jax.runtime.replay_store"):
        store = ReplayStore(d, FIELDS, chunk_rows=100)
    assert sorted(store.recovery["temp_removed"]) == ["chunk_000000005.npy.tmp", "index.json.tmp"]
    assert store.recovery["orphans_removed"] == ["chunk_000000005.npy"]
    dropped = store.recovery["dropped"]
    assert len(dropped) == 2 and "CRC-32" in dropped[0] and dropped[0].startswith("chunk_000000002")
    assert dropped[1].startswith("chunk_000000003")
    assert "dropping chunk 2" in caplog.text and "dropping chunk 3" in caplog.text
    assert _chunk_files(d) == ["chunk_000000000.npy", "chunk_000000001.npy", "chunk_000000004.npy"]
    assert (store.size, store.committed) == (300, 500)  # the cursor never goes back
    with pytest.raises(IndexError):
        store.read(200, 300)
    np.testing.assert_array_equal(store.read(400, 500)["idx"], np.arange(400, 500))
    sample = store.sample(5_000, np.random.default_rng(1))
    assert not np.isin(sample["idx"] // 100, [2, 3]).any() and set(sample["idx"] // 100) == {0, 1, 4}
    store.append(_rows(500, 100))  # new chunks go on after the cursor
    store.close()
    store = ReplayStore(d, FIELDS)  # the repaired index needs no further repair
    assert store.recovery == {"temp_removed": [], "orphans_removed": [], "dropped": []}
    assert (store.size, store.committed) == (400, 600)
    store.close()


def test_disk_budget_deletes_the_oldest_chunks_first(tmp_path):
    d = str(tmp_path)
    probe = ReplayStore(d + "/probe", FIELDS, chunk_rows=100)
    probe.append(_rows(0, 100))
    chunk_bytes = probe.disk_bytes
    probe.close()
    store = ReplayStore(d + "/s", FIELDS, chunk_rows=100, max_bytes=3 * chunk_bytes + 10)
    store.append(_rows(0, 1_000))
    assert store.num_chunks == 3 and store.disk_bytes <= 3 * chunk_bytes + 10
    assert (store.first_row, store.committed, store.size) == (700, 1_000, 300)
    assert _chunk_files(d + "/s") == [f"chunk_{i:09d}.npy" for i in (7, 8, 9)]
    np.testing.assert_array_equal(np.unique(store.sample(2_000, np.random.default_rng(2))["idx"] // 100), [7, 8, 9])
    store.close()
    with pytest.raises(ValueError, match="does not fit the disk budget"):
        ReplayStore(d + "/tiny", FIELDS, chunk_rows=100, max_bytes=chunk_bytes // 2)


def test_other_fields_and_a_second_writer_are_refused(tmp_path):
    d = str(tmp_path)
    store = ReplayStore(d, FIELDS, chunk_rows=10)
    with pytest.raises(StoreLockedError):
        ReplayStore(d, FIELDS)
    store.append(_rows(0, 10))
    store.close()
    with pytest.raises(StoreFormatError, match="holds rows"):
        ReplayStore(d, {**FIELDS, "obs": ((4,), np.dtype(np.float32))})
    with pytest.raises(FileNotFoundError):
        ReplayStore(str(tmp_path / "empty"))
    reopened = ReplayStore(d)  # fields from the index
    assert reopened.fields == FIELDS and reopened.committed == 10
    reopened.close()


def _write_ring_step(ring: ReplayBuffer, worker: int) -> None:
    """One env step of ``worker``: M rows whose idx is worker * 1e6 + the row's global index."""
    count = ring.count(worker)
    _, views = ring.rows(worker)
    idx = worker * 1_000_000 + count + np.arange(ring.envs_per_worker)
    views["idx"][:] = idx
    views["obs"][:] = np.stack([idx, -idx, idx % 7], axis=1)
    views["done"][:] = idx % 5 == 0
    ring.commit(worker)


def test_ring_spiller_copies_each_committed_row_once_and_counts_overruns(tmp_path):
    ring = ReplayBuffer.create(FIELDS, num_workers=2, envs_per_worker=4, capacity=40)
    store = ReplayStore(str(tmp_path), FIELDS, chunk_rows=16)
    try:
        spiller = RingSpiller(ring, store)
        expect = []
        for steps in (3, 0, 9, 5, 7):  # the ring region (10 steps) wraps around twice
            for _ in range(steps):
                for w in (0, 1):
                    _write_ring_step(ring, w)
            start = [int(c) for c in spiller.cursors]
            assert spiller.spill() == 2 * 4 * steps
            for w in (0, 1):
                expect.extend(w * 1_000_000 + np.arange(start[w], ring.count(w)))
        store.flush()
        got = store.read(0, store.committed)["idx"]
        np.testing.assert_array_equal(got, np.asarray(expect))
        _check_rows(store.read(0, store.committed))
        assert spiller.lost == 0
        # A learner that falls behind by more than the region loses the oldest rows, never reads torn ones.
        for _ in range(14):
            _write_ring_step(ring, 0)
        before = store.committed + store.pending
        n = spiller.spill()
        assert spiller.lost == 14 * 4 - (40 - 4) and n == 40 - 4
        store.flush()
        got = store.read(before, store.committed)["idx"]
        np.testing.assert_array_equal(got, 1_000_000 * 0 + np.arange(ring.count(0) - 36, ring.count(0)))
    finally:
        store.close()
        ring.close()


def test_rings_without_row_sums_commit_and_sample_the_same_rows_and_no_spiller_takes_them(tmp_path):
    """Runs without a replay store make their rings with ``row_sums=False``: commits skip the checksums (nothing
    else reads them), the rows and counters are the same, and a spiller refuses such a ring."""
    with_sums, without = (ReplayBuffer.create(FIELDS, num_workers=1, envs_per_worker=4, capacity=40, row_sums=flag)
                          for flag in (True, False))
    store = ReplayStore(str(tmp_path), FIELDS, chunk_rows=16)
    try:
        untouched = without._data[0]["_row_sum"].copy()
        for ring in (with_sums, without):
            for _ in range(3):
                _write_ring_step(ring, 0)
        assert with_sums.count(0) == without.count(0) == 12
        rows = {k: with_sums._data[0][k][:12] for k in FIELDS}
        np.testing.assert_array_equal(with_sums._data[0]["_row_sum"][:12], row_checksums(rows, 12))
        np.testing.assert_array_equal(without._data[0]["_row_sum"], untouched)
        rng = (np.random.default_rng(3) for _ in range(2))
        a, b = with_sums.sample(64, next(rng)), without.sample(64, next(rng))
        assert all(np.array_equal(a[k], b[k]) for k in FIELDS)
        with pytest.raises(ValueError, match="row_sums=True"):
            RingSpiller(without, store)
    finally:
        store.close()
        with_sums.close()
        without.close()


def test_tiered_sampler_mixes_every_minibatch_and_falls_back_to_a_nonempty_tier(tmp_path):
    store = ReplayStore(str(tmp_path), FIELDS, chunk_rows=50)
    hot_rows = {"n": 100}

    def hot_sample(n, rng):
        pick = rng.integers(0, 100, n)
        return {k: v[pick] for k, v in _rows(10_000, 100).items()}

    sampler = TieredSampler(lambda: hot_rows["n"], hot_sample, store, 0.25, ("idx", "obs"))
    rng = np.random.default_rng(3)
    assert (sampler.sample(4, 8, rng)["idx"] >= 10_000).all()  # disk still empty: all from the rings
    store.append(_rows(0, 50))
    batch = sampler.sample(4, 8, rng)
    assert set(batch) == {"idx", "obs"} and batch["obs"].shape == (32, 3)
    hot = (batch["idx"] >= 10_000).reshape(4, 8)
    assert hot[:, :2].all() and not hot[:, 2:].any()  # round(0.25 * 8) = 2 hot rows per minibatch
    np.testing.assert_array_equal(batch["obs"][:, 0], batch["idx"])
    hot_rows["n"] = 0  # right after a restart: the rings are empty
    assert (sampler.sample(4, 8, rng)["idx"] < 50).all()
    store.close()
    empty = ReplayStore(str(tmp_path / "e"), FIELDS)
    with pytest.raises(ValueError, match="both replay tiers are empty"):
        TieredSampler(lambda: 0, hot_sample, empty, 0.5, ("idx",)).sample(1, 4, rng)
    with pytest.raises(ValueError, match="hot_fraction"):
        TieredSampler(lambda: 0, hot_sample, empty, 1.5, ("idx",))
    empty.close()


_WRITER = """
import sys
import numpy as np
from unilab_jax.runtime.replay_store import ReplayStore
store = ReplayStore(sys.argv[1], {"idx": ((), np.int64), "obs": ((3,), np.float32), "done": ((), bool)},
                    chunk_rows=2_000, max_bytes=int(sys.argv[2]))
n = store.committed
print(n, flush=True)
while True:
    idx = np.arange(n, n + 700, dtype=np.int64)
    store.append({"idx": idx, "obs": np.stack([idx, -idx, idx % 7], 1).astype(np.float32), "done": idx % 5 == 0})
    n += 700
    if n % 9_800 == 0:
        store.flush()
"""


def test_store_killed_at_random_moments_reopens_consistent(tmp_path):
    """A writer process appending, committing, flushing and evicting is SIGKILLed at random moments;
    each reopen must find no temp files, exactly the indexed chunks, every committed row intact."""
    d = str(tmp_path / "store")
    chunk_bytes = 2_000 * 21 + 256
    rnd = random.Random(1234)
    committed = 0
    for _ in range(5):
        p = subprocess.Popen([sys.executable, "-c", _WRITER, d, str(12 * chunk_bytes)], cwd=ROOT,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        start = int(p.stdout.readline())  # the writer has opened the store
        assert start == committed
        time.sleep(rnd.uniform(0.05, 0.6))
        os.kill(p.pid, signal.SIGKILL)
        p.wait()
        with open(os.path.join(d, "index.json")) as f:
            index = json.load(f)
        listed = {f"chunk_{c[0]:09d}.npy" for c in index["chunks"]}
        store = ReplayStore(d)
        assert not [n for n in os.listdir(d) if n.endswith(".tmp")]
        assert set(_chunk_files(d)) == listed and store.recovery["dropped"] == []
        assert store.committed == index["committed"] >= committed and store.disk_bytes <= 12 * chunk_bytes
        rows = store.read(store.first_row, store.committed)
        np.testing.assert_array_equal(rows["idx"], np.arange(store.first_row, store.committed))
        _check_rows(rows)
        committed = store.committed
        store.close()
    assert committed > 20 * 2_000  # the writers got far enough to evict (budget: 12 chunks)


def test_a_damaged_index_is_named(tmp_path):
    """Issue 34: every one-bit flip in index.json, and a truncated index, is a StoreCorruptError naming the file
    and what to do, never a raw JSONDecodeError or a store reopened with other contents."""
    d = str(tmp_path / "store")
    with ReplayStore(d, FIELDS, chunk_rows=50, info={"task": "t"}) as store:
        store.append(_rows(0, 120))
        store.flush()
    path = os.path.join(d, "index.json")
    good = open(path, "rb").read()
    assert json.loads(good)["version"] == 2 and "sha256" in json.loads(good)
    for i in range(len(good)):
        with open(path, "wb") as f:
            f.write(good[:i] + bytes([good[i] ^ (1 << (i % 8))]) + good[i + 1:])
        with pytest.raises(StoreCorruptError) as e:
            ReplayStore(d, FIELDS).close()
        assert path in str(e.value) and "--resume" in str(e.value), (i, str(e.value))
    with open(path, "wb") as f:
        f.write(good[:100])
    with pytest.raises(StoreCorruptError, match=f"replay store index {path} is damaged: not readable JSON"):
        ReplayStore(d, FIELDS)
    # An index written before digests (version 1) still opens.
    doc = json.loads(good)
    del doc["sha256"]
    with open(path, "w") as f:
        json.dump({**doc, "version": 1}, f)
    with ReplayStore(d, FIELDS) as store:
        assert store.committed == 120 and store.info == {"task": "t"}
        _check_rows(store.read(store.first_row, store.committed))
