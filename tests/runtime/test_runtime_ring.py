"""SPSC slot rings and trajectory slots: ordering, fullness, checksums, cross-process stress."""

from __future__ import annotations

import multiprocessing as mp
import time

import numpy as np
import pytest
import rt_helpers

from unilab_jax.runtime.buffers import SlotCorruptError, TrajectoryBuffer
from unilab_jax.runtime.ring import SpscRing, checksum, ring_words
from unilab_jax.runtime.shm import SharedArrays


def _ring(capacity: int):
    seg = SharedArrays.create({"r": ((ring_words(capacity),), np.int64)})
    ring = SpscRing(seg["r"])
    ring.init()
    return seg, ring


def test_ring_fifo_full_empty_and_many_laps():
    seg, ring = _ring(4)
    try:
        assert ring.capacity == 4 and ring.pop() is None and len(ring) == 0
        for lap in range(1000):  # sequences keep growing; entries are reused every 4 pushes
            vals = [(lap * 7 + i) % 2**32 for i in range(4)]
            seqs = [ring.push(v) for v in vals]
            assert seqs == list(range(lap * 4, lap * 4 + 4))
            assert ring.push(1) is None, "a full ring must refuse"
            assert len(ring) == 4
            assert [ring.pop() for _ in range(4)] == list(zip(vals, seqs, strict=True))
            assert ring.pop() is None
    finally:
        seg.close()


def test_ring_ignores_stale_and_poison_entries():
    seg, ring = _ring(2)
    try:
        ring.push(5)
        assert ring.pop() == (5, 0)
        # The entry for sequence 0 is still in memory at index 0; after one more lap it must not be
        # mistaken for sequence 2.
        ring.push(6)
        assert ring.pop() == (6, 1)
        assert ring.peek() is None
        ring.entries[:] = -1  # poison never looks published
        assert ring.peek() is None
        with pytest.raises(ValueError):
            ring.push(2**32)
    finally:
        seg.close()


def test_checksum_depends_on_data_and_sequence():
    a = np.arange(64, dtype=np.float32).view(np.uint8)
    c0 = checksum(a, 0)
    assert c0 == checksum(a.copy(), 0)
    assert c0 != checksum(a, 1)
    b = a.copy()
    b[5] ^= 1
    assert checksum(b, 0) != c0
    assert 0 <= c0 < 2**63


def _buffer(workers=1, slots=2, t=4, m=8):
    return TrajectoryBuffer.create(rt_helpers.PATTERN_FIELDS, workers, m, t, slots)


def test_slot_roundtrip_and_corruption_is_detected():
    buf = _buffer()
    try:
        assert buf.take(0) is None
        slot = buf.try_acquire(0)
        views = buf.slot(0, slot)
        assert np.isnan(views["a"]).all() and (views["b"] == -1).all()  # poison-filled
        rt_helpers.fill_pattern(views, 3)
        seq = buf.publish(0, slot)
        assert buf.ready(0) == 1
        got = buf.take(0)
        assert got == (slot, seq)
        out = buf.empty_batch(1)
        buf.copy_slot(0, slot, out)
        assert rt_helpers.pattern_ok(out, 3)
        buf.release(0, slot)

        # A slot whose bytes change after publication (a torn / half-visible write) is refused.
        slot = buf.try_acquire(0)
        rt_helpers.fill_pattern(buf.slot(0, slot), 4)
        buf.publish(0, slot)
        buf.slot(0, slot)["e"][1, 2, 3] = 9.0
        with pytest.raises(SlotCorruptError):
            buf.take(0, verify_timeout=0.2)
        # A stale checksum from the slot's previous use does not validate new data either.
        buf.slot(0, slot)["e"][1, 2, 3] = 4.0
        assert buf.take(0) is not None
    finally:
        buf.close()


def test_slot_rings_cross_process_stress():
    """A producer process publishes 3000 pattern-filled slots; every slot read is complete."""
    n = 3000
    buf = TrajectoryBuffer.create(rt_helpers.PATTERN_FIELDS, 1, 64, 2, 3)  # ~40 kB slots, 3 slots
    ctx = mp.get_context("spawn")
    proc = ctx.Process(target=rt_helpers.slot_producer, args=(buf.handle, 0, n, 60.0))
    proc.start()
    try:
        out = buf.empty_batch(1)
        bad, expected_seq = [], 0
        deadline = time.monotonic() + 60
        for i in range(n):
            while (got := buf.take(0)) is None:
                assert proc.is_alive() or buf.ready(0), f"producer died (exit {proc.exitcode})"
                assert time.monotonic() < deadline, "stress test timed out"
            slot, seq = got
            assert seq == expected_seq
            expected_seq += 1
            buf.copy_slot(0, slot, out)
            if not rt_helpers.pattern_ok(out, i):
                bad.append(i)
            if i % 2:  # vary timing: release at once or after the copy is re-checked
                time.sleep(0)
            buf.release(0, slot)
        proc.join(30)
        assert proc.exitcode == 0
        assert not bad, f"torn or stale slots read: {bad[:10]}"
    finally:
        if proc.is_alive():
            proc.kill()
            proc.join()
        buf.close()
