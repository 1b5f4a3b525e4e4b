"""WorkerPool end to end on cartpole: exact data path, versions, replay, failures, shutdown."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest
import toy_algo

import tasks
from unilab_jax.config import ConfigError
from unilab_jax.runtime import WorkerDiedError, WorkerPool
from unilab_jax.runtime.shm import list_segments

pytestmark = pytest.mark.timeout(120)

TASK = "cartpole_balance"
OVERRIDES = {"episode_length": 12}  # episodes end (truncate + auto-reset) inside every batch
W, M, T, SEED = 2, 4, 8, 3


def _weights(version: int) -> dict:
    rng = np.random.default_rng(100 + version)
    return {"w": rng.standard_normal((1, 5)).astype(np.float32),
            "log_std": np.full((1,), -1.0 + 0.1 * version, np.float32)}


def _pool(algo="toy_algo", serial=False, **kw) -> WorkerPool:
    args = dict(num_workers=W, envs_per_worker=M, seed=SEED, algo_module=algo, weight_template=_weights(0),
                horizon=T, slots_per_worker=2, serial=serial)
    args.update(kw)
    return WorkerPool(TASK, OVERRIDES, **args)


def _reference(worker_id: int, n_versions: int) -> list[dict[str, np.ndarray]]:
    """What worker ``worker_id`` must write, computed here without the runtime."""
    seed = SEED * 1000 + worker_id
    task = tasks.make(TASK, M, seed, OVERRIDES)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5EED]))
    obs, cobs = task.reset()
    ret, length = np.zeros(M, np.float32), np.zeros(M, np.int32)
    out = []
    for v in range(n_versions):
        rec: dict[str, list] = {}
        for _ in range(T):
            noise = rng.standard_normal((M, 1), dtype=np.float32)
            action, ex = toy_algo.act(_weights(v), obs, noise)
            res = task.step(action)
            ret += res.reward
            length += 1
            row = {
                "obs": obs, "critic_obs": cobs, "action": action, "reward": res.reward,
                "terminated": res.terminated, "truncated": res.truncated, "next_obs": res.next_obs,
                "next_critic_obs": res.next_critic_obs,
                "reward_terms": np.stack([res.reward_terms[k] for k in task.spec.reward_terms], -1),
                "episode_return": ret.copy(), "episode_length": length.copy(),
                "policy_version": np.full(M, v, np.int64), "log_prob": ex["log_prob"],
            }
            for k, x in row.items():
                rec.setdefault(k, []).append(np.array(x))
            done = res.terminated | res.truncated
            ret[done], length[done] = 0.0, 0
            obs, cobs = res.obs, res.critic_obs
        out.append({k: np.stack(x) for k, x in rec.items()})
    task.close()
    return out


@pytest.fixture(scope="module")
def reference():
    return [_reference(w, 3) for w in range(W)]


@pytest.mark.parametrize("serial", [True, False], ids=["serial", "processes"])
def test_lockstep_batches_are_exactly_what_workers_computed(serial, reference):
    pool = _pool(serial=serial).start()
    any_done = False
    try:
        for v in range(3):
            pool.publish(_weights(v), v)
            batch, info = pool.collect(timeout=60)
            assert info["workers"] == [0, 1]
            assert info["policy_version_min"] == info["policy_version_max"] == v
            assert set(batch) == set(pool.fields)
            for w in range(W):
                cols = slice(w * M, (w + 1) * M)
                for name, want in reference[w][v].items():
                    got = batch[name][:, cols]
                    assert got.dtype == pool.fields[name][1], name
                    np.testing.assert_array_equal(got, want.astype(got.dtype), err_msg=f"{name} w{w} v{v}")
            # Semantics the buffer must keep: successor obs, episode bookkeeping, both done flags.
            done = batch["terminated"] | batch["truncated"]
            any_done |= bool(done.any())
            assert not (batch["terminated"] & batch["truncated"]).any()
            cont = ~done[:-1]
            np.testing.assert_array_equal(batch["obs"][1:][cont], batch["next_obs"][:-1][cont])
            np.testing.assert_allclose(batch["reward"], batch["reward_terms"].sum(-1), rtol=1e-5, atol=1e-6)
        assert any_done
        stats = pool.stats()
        assert stats["env_steps"] == 3 * W * M * T
        assert stats["worker_policy_versions"] == [2, 2]
        assert stats["episodes"] > 0 and stats["episode_length_mean"] <= OVERRIDES["episode_length"]
        assert set(stats["reward_terms"]) == set(pool.spec.reward_terms)
        if not serial:
            assert stats["workers_with_jax"] == 0
            assert all(pid != os.getpid() for pid in stats["worker_pids"])
    finally:
        pool.close()
    assert not set(pool.segment_names) & set(list_segments())


def test_lockstep_waits_for_a_newer_version():
    pool = _pool().start()
    try:
        pool.publish(_weights(0), 0)
        pool.collect(timeout=60)
        time.sleep(0.3)  # workers hold free slots but must not start a chunk on version 0 again
        assert pool.env_steps() == W * M * T
        with pytest.raises(TimeoutError):
            pool.collect(timeout=0.3)
        pool.publish(_weights(1), 1)
        batch, _ = pool.collect(timeout=60)
        assert (batch["policy_version"] == 1).all()
        with pytest.raises(ValueError, match="one slot per worker"):
            pool.collect(n_slots=1)
    finally:
        pool.close()


def test_serial_lockstep_without_new_weights_is_an_error():
    pool = _pool(serial=True).start()
    try:
        with pytest.raises(RuntimeError, match="publish"):
            pool.collect()
    finally:
        pool.close()


def test_async_versions_are_monotone_and_never_ahead():
    pool = _pool(algo="toy_algo_async").start()
    try:
        pool.publish(_weights(0), 0)
        per_worker: dict[int, list[np.ndarray]] = {0: [], 1: []}
        for v in range(1, 6):
            batch, info = pool.collect(n_slots=3, timeout=60)
            assert info["policy_version_max"] <= pool.version
            assert (batch["policy_version"] >= 0).all()
            for j, w in enumerate(info["workers"]):
                per_worker[w].append(batch["policy_version"][:, j * M : (j + 1) * M])
            pool.publish(_weights(v), v)
        for w, chunks in per_worker.items():
            seq = np.concatenate(chunks, axis=0)  # time-major over this worker's slots, in order
            assert (np.diff(seq, axis=0) >= 0).all(), f"worker {w} versions went backwards"
            assert (seq == seq[:, :1]).all(), "all envs of a step share one version"
        assert pool.stats()["workers_with_jax"] == 0
    finally:
        pool.close()


def test_async_workers_act_with_whole_large_weights():
    """Weights of PREFETCH_MIN_BYTES (a worker process copies them in its prefetch thread): every action is
    the one of the version stamped on its row (w = version, a near-zero std), published while collecting."""
    from unilab_jax.runtime.worker import PREFETCH_MIN_BYTES

    def big(version: int) -> dict:
        return {"w": np.full((1, 5), float(version), np.float32), "log_std": np.full((1,), -30.0, np.float32),
                "ballast": np.full(PREFETCH_MIN_BYTES // 4, float(version), np.float32)}

    pool = _pool(algo="toy_algo_async", weight_template=big(0)).start()
    try:
        for v in range(1, 6):
            pool.publish(big(v), v)
            deadline = time.monotonic() + 30
            while True:  # the prefetch thread hands a version over a few ms after its publish
                batch, _ = pool.collect(n_slots=2, timeout=60)
                stamped = batch["policy_version"].astype(np.float32)
                expected = stamped[..., None] * batch["obs"].sum(-1, keepdims=True)
                np.testing.assert_allclose(batch["action"], expected, rtol=1e-5, atol=1e-5)
                if (batch["policy_version"] == v).any():
                    break
                assert time.monotonic() < deadline, f"version {v} never reached the workers"
    finally:
        pool.close()


@pytest.mark.parametrize("serial", [True, False], ids=["serial", "processes"])
def test_replay_sampling(serial):
    pool = _pool(algo="toy_algo_replay", serial=serial, replay_capacity=30).start()
    try:
        assert pool.buffer.capacity == 32  # rounded up to a multiple of M
        pool.publish(_weights(0), 0)
        with pytest.raises(ValueError, match="capacity"):
            pool.wait_replay(W * 32 + 1)
        pool.wait_replay(W * 32, timeout=60)
        assert pool.replay_size() == W * 32
        pool.pump(12)  # serial: steps the workers; processes: they run on their own
        deadline = time.monotonic() + 60
        while pool.env_steps() < 2 * W * 32:  # every region has wrapped at least once
            assert time.monotonic() < deadline
            time.sleep(0.01)
        rng = np.random.default_rng(0)
        batch = pool.sample(512, rng)
        assert set(batch) == set(pool.fields) and batch["obs"].shape == (512, 5)
        assert (batch["policy_version"] >= 0).all() and np.isfinite(batch["obs"]).all()
        assert (batch["episode_length"] >= 1).all()
        np.testing.assert_allclose(batch["reward"], batch["reward_terms"].sum(-1), rtol=1e-5, atol=1e-6)
        std = np.exp(_weights(0)["log_std"])
        mean = batch["obs"] @ _weights(0)["w"].T
        want = -0.5 * np.sum(((batch["action"] - mean) / std) ** 2 + 2 * np.log(std) + np.log(2 * np.pi), -1)
        np.testing.assert_allclose(batch["log_prob"], want, rtol=1e-4, atol=1e-4)
        with pytest.raises(RuntimeError, match="trajectory"):
            pool.collect()
    finally:
        pool.close()


def test_killed_worker_is_reported_when_restarts_are_off():
    pool = _pool(max_restarts=0).start()
    try:
        pool.publish(_weights(0), 0)
        pool.collect(timeout=60)
        pid = pool.stats()["worker_pids"][1]
        os.kill(pid, signal.SIGKILL)
        pool.publish(_weights(1), 1)
        t0 = time.monotonic()
        with pytest.raises(WorkerDiedError, match="worker 1 .* exited with code -9"):
            pool.collect(timeout=60)
        assert time.monotonic() - t0 < 10
    finally:
        pool.close()


def test_crashing_policy_reports_the_traceback():
    pool = _pool(algo="toy_algo_crash").start()
    try:
        pool.publish(_weights(0), 0)
        with pytest.raises(WorkerDiedError, match="exploded on purpose"):
            pool.collect(timeout=60)
    finally:
        pool.close()


@pytest.mark.parametrize("algo", ["toy_algo", "toy_algo_async"])
def test_close_is_fast_idempotent_and_unlinks(algo):
    pool = _pool(algo=algo).start()
    procs = [p for p in pool._procs]
    pool.publish(_weights(0), 0)
    time.sleep(0.3)  # lockstep: blocked after one slot; async: running
    names = pool.segment_names
    assert set(names) <= set(list_segments())
    t0 = time.monotonic()
    pool.close()
    assert time.monotonic() - t0 < 5.0
    pool.close()
    assert not any(p.is_alive() for p in procs)
    assert all(p.exitcode == 0 for p in procs), [p.exitcode for p in procs]  # stopped by the flag
    assert not set(names) & set(list_segments())
    with pytest.raises(RuntimeError, match="closed"):
        pool.collect()


def test_stop_ends_the_workers_and_keeps_the_rings_until_close():
    """``stop`` is ``close``'s first half (the trainer reads the rings in between, training/ring_snapshot.py)."""
    pool = _pool(algo="toy_algo_replay", replay_capacity=30).start()
    procs, names = list(pool._procs), pool.segment_names
    try:
        pool.publish(_weights(0), 0)
        pool.wait_replay(W * 8, timeout=60)
        pool.stop()
        assert not any(p.is_alive() for p in procs)
        assert all(p.exitcode == 0 for p in procs), [p.exitcode for p in procs]  # stopped by the flag
        counts = pool.buffer.counts()
        time.sleep(0.2)
        assert (pool.buffer.counts() == counts).all() and counts.sum() >= W * 8  # nothing writes any more
        assert set(names) <= set(list_segments())
        assert np.isfinite(pool.buffer.sample(64, np.random.default_rng(0))["obs"]).all()
        with pytest.raises(RuntimeError, match="stopped"):  # the stopped workers are not respawned
            pool.before_sample()
    finally:
        pool.close()
    assert not set(names) & set(list_segments())


def test_invalid_configuration_fails_before_anything_starts():
    ours = f"unilab_{os.getpid()}_"  # other test processes (pytest-xdist) create segments meanwhile
    before = set(list_segments(ours))
    with pytest.raises(ValueError, match="unknown task"):
        WorkerPool("no_such_task", {}, 1, 1, 0, "toy_algo", _weights(0))
    with pytest.raises(ConfigError):
        WorkerPool(TASK, {"no_such_key": 1}, 1, 1, 0, "toy_algo", _weights(0))
    with pytest.raises(ValueError, match="replay_capacity"):
        WorkerPool(TASK, {}, 1, 1, 0, "toy_algo_replay", _weights(0))
    with pytest.raises(ModuleNotFoundError):
        WorkerPool(TASK, {}, 1, 1, 0, "no_such_algo_module", _weights(0))
    assert set(list_segments(ours)) == before
