"""Weight channel: round trip of a nested pytree, version rules, torn copies never accepted."""

from __future__ import annotations

import multiprocessing as mp
import threading
import time
from typing import NamedTuple

import numpy as np
import pytest
import rt_helpers

from unilab_jax.runtime.ring import RingTimeout
from unilab_jax.runtime.shm import SharedArrays
from unilab_jax.runtime.weights import WeightChannel, WeightPrefetcher, WeightPublisher, WeightReader


class Stats(NamedTuple):
    mean: np.ndarray
    var: np.ndarray
    count: np.ndarray


def _tree(rng):
    # dict insertion order deliberately unsorted: flattening must follow sorted keys both ways.
    return {
        "zeta": rng.standard_normal((3,)).astype(np.float32),
        "actor": [{"w": rng.standard_normal((5, 4)).astype(np.float32), "b": np.zeros(4, np.float32)},
                  {"w": rng.standard_normal((4, 2)).astype(np.float32), "b": np.ones(2, np.float32)}],
        "obs_norm": Stats(rng.standard_normal(5).astype(np.float32), np.ones(5, np.float32),
                          np.array(17.0, np.float32)),
        "steps": np.array([3], np.int64),
    }


def _assert_tree_equal(a, b):
    if isinstance(a, dict):
        assert list(a) == list(b)
        for k in a:
            _assert_tree_equal(a[k], b[k])
    elif isinstance(a, list | tuple):
        assert type(a) is type(b) and len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_tree_equal(x, y)
    else:
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)


def test_roundtrip_versions_and_normalizer_leaves():
    rng = np.random.default_rng(0)
    ch = WeightChannel(_tree(rng))
    reader = WeightReader(ch.handle)
    try:
        assert reader.latest_version() == -1 and reader.poll() is None
        with pytest.raises(RingTimeout):
            reader.read(min_version=0, timeout=0.1)
        trees = [_tree(rng) for _ in range(3)]
        for v, t in enumerate(trees):
            ch.publish(t, v)
            got, version = reader.read(min_version=v)
            assert version == v
            _assert_tree_equal(got, t)
            assert isinstance(got["obs_norm"], Stats)
            assert reader.poll() is None  # nothing newer
        ch.publish(trees[0], 10)
        got, version = reader.poll()
        assert version == 10
        _assert_tree_equal(got, trees[0])
        with pytest.raises(ValueError, match="increase"):
            ch.publish(trees[0], 10)
        bad = _tree(rng)
        bad["actor"][0]["w"] = np.zeros((5, 5), np.float32)
        with pytest.raises(ValueError, match="actor/0/w"):
            ch.publish(bad, 11)
    finally:
        reader.close()
        ch.close()


def test_reader_refuses_a_corrupted_buffer_and_keeps_its_previous_tree():
    ch = WeightChannel(rt_helpers.weight_tree(0.0))
    reader = WeightReader(ch.handle)
    try:
        ch.publish(rt_helpers.weight_tree(1.0), 1)
        tree, _ = reader.read()
        active = int(ch.seg["header"][0])
        ch.seg["data"][active, 100] ^= 0xFF  # what a torn copy looks like to the checksum
        assert reader._try_read() is None and reader.retries == 1
        with pytest.raises(RingTimeout):
            reader.read(min_version=1, timeout=0.2)
        assert np.all(tree["actor"][0]["w"] == 1.0), "a failed read must not clobber the last good tree"
    finally:
        reader.close()
        ch.close()


def _leaves_equal(tree, value: float) -> bool:
    a = tree["actor"]
    return all(bool((x == value).all()) for x in (a[0]["w"], a[0]["b"], a[1]["w"], a[1]["b"], tree["log_std"],
                                                   tree["obs_norm"]["mean"], tree["obs_norm"]["count"]))


def test_prefetcher_hands_over_whole_versions_and_never_touches_the_held_copy():
    """A writer thread publishes value == version trees nonstop; the copy the caller holds must stay whole
    until it takes a newer one (the prefetch thread may only reuse the buffer of the copy taken before)."""
    ch = WeightChannel(rt_helpers.weight_tree(0.0))
    reader = WeightReader(ch.handle)
    with pytest.raises(ValueError, match="first read"):
        WeightPrefetcher(reader)
    ch.publish(rt_helpers.weight_tree(0.0), 0)
    tree, version = reader.read()
    prefetch = WeightPrefetcher(reader, interval_s=0.0002)
    stop = threading.Event()

    def write():
        v = 1
        while not stop.is_set():
            ch.publish(rt_helpers.weight_tree(float(v)), v)
            v += 1

    writer = threading.Thread(target=write)
    writer.start()
    taken = []
    try:
        deadline = time.monotonic() + 60
        while len(taken) < 100 and time.monotonic() < deadline:
            assert _leaves_equal(tree, float(version)), f"the held copy of version {version} changed"
            got = prefetch.take()
            if got is not None:
                assert got[1] > version
                tree, version = got
                assert _leaves_equal(tree, float(version)), f"version {version} handed over torn"
                taken.append(version)
            time.sleep(0.0005)
    finally:
        stop.set()
        writer.join()
        prefetch.close()
        reader.close()
        ch.close()
    assert len(taken) == 100, f"only {len(taken)} versions handed over in 60 s"
    assert taken[-1] - taken[0] > len(taken), "the writer hardly raced the prefetch thread"
    assert not prefetch._thread.is_alive()


def test_publisher_does_not_block_the_learner_and_the_newest_version_wins():
    """While the thread is inside a (held) publish, submit returns at once; versions submitted meanwhile
    replace each other; flush writes the newest; the channel ends on it, whole."""
    ch = WeightChannel(rt_helpers.weight_tree(0.0))
    release, entered, written = threading.Event(), threading.Event(), []

    def publish(tree, version):
        entered.set()
        assert release.wait(30)
        ch.publish(tree, version)
        written.append(version)

    pub = WeightPublisher(publish)
    pub.submit(rt_helpers.weight_tree(1.0), 1)
    assert entered.wait(30)
    for v in (2, 3, 4):  # the thread is held inside version 1's publish: these must not wait for it
        pub.submit(rt_helpers.weight_tree(float(v)), v)
    assert written == [] and pub.skipped == 2
    release.set()
    pub.flush()
    assert written == [1, 4] and pub.published_version == 4
    reader = WeightReader(ch.handle)
    tree, version = reader.read()
    assert version == 4 and _leaves_equal(tree, 4.0)
    pub.submit(rt_helpers.weight_tree(5.0), 5)
    pub.close()  # writes the last submitted version before stopping
    assert written[-1] == 5 and not pub._thread.is_alive()
    with pytest.raises(RuntimeError, match="closed"):
        pub.submit(rt_helpers.weight_tree(6.0), 6)
    reader.close()
    ch.close()


def test_publisher_raises_the_thread_failure_at_the_next_call():
    ch = WeightChannel(rt_helpers.weight_tree(0.0))
    pub = WeightPublisher(ch.publish)
    pub.submit(rt_helpers.weight_tree(1.0), 1)
    pub.flush()
    pub.submit(rt_helpers.weight_tree(1.0), 1)  # not newer: the channel refuses it in the thread
    with pytest.raises(RuntimeError, match="publishing weights failed: weight versions must increase"):
        pub.flush()
    with pytest.raises(RuntimeError, match="publishing weights failed"):
        pub.submit(rt_helpers.weight_tree(2.0), 2)
    with pytest.raises(RuntimeError, match="publishing weights failed"):
        pub.close()
    ch.close()


def test_weights_cross_process_stress_never_torn():
    """Writer process publishes value == version trees nonstop; reader process reads 3000 times."""
    ctl = SharedArrays.create({"flags": ((8,), np.int64)})
    ctl["flags"][:] = 0
    ctx = mp.get_context("spawn")
    box, results = ctx.Queue(), ctx.Queue()
    writer = ctx.Process(target=rt_helpers.weights_writer, args=(box, ctl.handle, 60.0))
    reader = ctx.Process(target=rt_helpers.weights_reader, args=(box, ctl.handle, 3000, results))
    writer.start()
    reader.start()
    try:
        res = results.get(timeout=90)
        reader.join(30)
        writer.join(30)
        assert reader.exitcode == 0 and writer.exitcode == 0
        assert res["torn"] == 0, res
        assert res["non_monotone"] == 0, res
        assert res["distinct"] > 50, f"the writer hardly raced the reader: {res}"
        assert ctl["flags"][1] > 100, "the writer published too little to stress anything"
    finally:
        for p in (writer, reader):
            if p.is_alive():
                p.kill()
                p.join()
        ctl.close()
