"""Fault injection on the real runtime: killed, stopped and crashing workers, non-finite data, the
replay env-step limit. Worker processes are spawned as in training; every test runs in seconds."""

from __future__ import annotations

import json
import os
import signal
import time

import numpy as np
import pytest
import toy_algo_nanact
import toy_nan_task

from unilab_jax.runtime import WorkerDiedError, WorkerPool
from unilab_jax.runtime.buffers import TrajectoryBuffer
from unilab_jax.runtime.ring import checksum
from unilab_jax.runtime.worker import CHUNKS, HEARTBEAT, PID, READY, STATUS, STEPS

pytestmark = pytest.mark.timeout(120)

W, M, T = 2, 4, 8
CARTPOLE = ("cartpole_balance", {"episode_length": 12})


def _weights(obs_dim: int, version: int = 0) -> dict:
    rng = np.random.default_rng(100 + version)
    return {"w": rng.standard_normal((1, obs_dim)).astype(np.float32), "log_std": np.full((1,), -1.0, np.float32)}


def _pool(algo: str, task=CARTPOLE, obs_dim: int = 5, **kw) -> WorkerPool:
    args = dict(num_workers=W, envs_per_worker=M, seed=5, algo_module=algo, weight_template=_weights(obs_dim),
                horizon=T, slots_per_worker=2)
    args.update(kw)
    return WorkerPool(task[0], task[1], **args)


def _float_fields_finite(batch: dict) -> None:
    for name, a in batch.items():
        if a.dtype.kind == "f":
            assert np.isfinite(a).all(), name


def _wait(cond, timeout: float = 30.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.005)


def _words(pool: WorkerPool) -> np.ndarray:
    return pool._ctl["worker"]


# ---- slot recovery (no processes) -------------------------------------------------------------
def test_reclaim_returns_the_dead_writers_slot_and_completes_a_half_done_publish():
    fields = {"x": ((3,), np.dtype(np.float32))}
    buf = TrajectoryBuffer.create(fields, num_workers=1, envs_per_worker=2, horizon=4, slots_per_worker=3)
    try:
        s0 = buf.try_acquire(0)
        buf.slot(0, s0)["x"][...] = 1.0
        buf.publish(0, s0)
        assert buf.take(0) == (s0, 0)  # the learner holds s0
        s1 = buf.try_acquire(0)
        buf.slot(0, s1)["x"][...] = np.nan  # the worker dies half way through s1
        assert buf.reclaim(0, held={s0}) == [s1]
        assert sorted(buf.free[0].pending()) == sorted({0, 1, 2} - {s0})
        # A publish cut between its publishing store and its count update: the slot is whole.
        s2 = buf.try_acquire(0)
        buf.slot(0, s2)["x"][...] = 2.0
        ring = buf.full[0]
        seq = ring.next_sequence()
        buf._sums[0, s2] = checksum(buf._slot_bytes(0, s2), seq)
        ring.entries[seq & (ring.capacity - 1)] = (seq << 32) | s2  # the store; the count update never ran
        assert buf.reclaim(0, held={s0}) == []
        assert ring.write_count == seq + 1
        # The next process's publish lands under the next sequence, and the learner gets both in order.
        s3 = buf.try_acquire(0)
        buf.slot(0, s3)["x"][...] = 3.0
        buf.publish(0, s3)
        got = [buf.take(0), buf.take(0)]
        assert [g[0] for g in got] == [s2, s3] and [g[1] for g in got] == [seq, seq + 1]
        assert buf.slot(0, s2)["x"][0, 0, 0] == 2.0
    finally:
        buf.close()


# ---- killed and stopped workers ---------------------------------------------------------------
def test_workers_killed_mid_slot_are_respawned_and_lockstep_goes_on(monkeypatch):
    monkeypatch.setenv("TOY_HANG_AT_CALL", str(T + 3))  # both first processes stop 3 steps into slot 2
    pool = _pool("toy_algo_hang", max_restarts=3).start()
    words = _words(pool)
    chunk = T * M
    try:
        pool.publish(_weights(5, 0), 0)
        pool.collect(timeout=60)
        # 1) SIGKILL both while they are writing their slots for version 1.
        pool.publish(_weights(5, 1), 1)
        _wait(lambda: (words[:, STEPS] == chunk + 3 * M).all(), what="workers mid-slot")
        monkeypatch.delenv("TOY_HANG_AT_CALL")  # the respawned processes run normally
        old_pids = words[:, PID].tolist()
        for pid in old_pids:
            os.kill(pid, signal.SIGKILL)
        t0 = time.monotonic()
        batch, info = pool.collect(timeout=60)
        assert time.monotonic() - t0 < 10
        assert info["policy_version_min"] == info["policy_version_max"] == 1
        _float_fields_finite(batch)
        stats = pool.stats()
        assert stats["worker_restarts"] == 2 and not set(stats["worker_pids"]) & set(old_pids)
        # 2) SIGKILL after worker 1 published its version-2 slot: the learner still gets that slot, and
        #    the new process resumes after it (no second version-2 slot in the next collect).
        chunks = int(words[1, CHUNKS])  # counted across its processes
        pool.publish(_weights(5, 2), 2)
        _wait(lambda: words[1, CHUNKS] > chunks, what="worker 1's version-2 slot")
        os.kill(int(words[1, PID]), signal.SIGKILL)
        batch, info = pool.collect(timeout=60)
        assert info["policy_version_min"] == info["policy_version_max"] == 2
        with pytest.raises(TimeoutError):  # no version 3 yet; the pool respawns worker 1 meanwhile
            pool.collect(timeout=1.0)
        _wait(lambda: pool.stats()["worker_restarts"] == 3 and words[1, STATUS] == READY, what="respawn")
        time.sleep(0.3)  # a new process resuming at the wrong version would publish a version-2 slot now
        for v in (3, 4):
            pool.publish(_weights(5, v), v)
            batch, info = pool.collect(timeout=60)
            assert info["policy_version_min"] == info["policy_version_max"] == v
            _float_fields_finite(batch)
        assert pool.stats()["worker_restarts"] == 3
        # Every slot is back in its free ring (lock-step workers wait for weights holding none).
        assert [sorted(pool.buffer.free[w].pending()) for w in range(W)] == [[0, 1], [0, 1]]
        # 3) Restarts exhausted: the next death raises, naming the worker.
        os.kill(int(words[0, PID]), signal.SIGKILL)
        pool.publish(_weights(5, 5), 5)
        with pytest.raises(WorkerDiedError, match=r"worker 0 .*code -9.*max_restarts=3"):
            pool.collect(timeout=60)
    finally:
        pool.close()


def test_stopped_worker_is_found_by_its_heartbeat_and_replaced():
    pool = _pool("toy_algo", heartbeat_timeout=1.0).start()
    words = _words(pool)
    try:
        pool.publish(_weights(5, 0), 0)
        pool.collect(timeout=60)
        beat = int(words[1, HEARTBEAT])
        time.sleep(0.3)  # both workers are blocked waiting for version 1: they still beat
        assert words[1, HEARTBEAT] > beat
        stopped, healthy = int(words[0, PID]), int(words[1, PID])
        os.kill(stopped, signal.SIGSTOP)
        pool.publish(_weights(5, 1), 1)
        t0 = time.monotonic()
        batch, info = pool.collect(timeout=60)
        assert 1.0 <= time.monotonic() - t0 < 10
        assert info["policy_version_min"] == info["policy_version_max"] == 1
        stats = pool.stats()
        assert stats["worker_restarts"] == 1 and stats["worker_pids"][1] == healthy
        assert stats["worker_pids"][0] != stopped
        with pytest.raises(ProcessLookupError):
            os.kill(stopped, 0)  # killed and reaped
    finally:
        pool.close()


def test_replay_worker_killed_mid_step_is_respawned():
    pool = _pool("toy_algo_replay_slow", replay_capacity=64).start()
    words = _words(pool)
    try:
        pool.publish(_weights(5, 0), 0)
        pool.wait_replay(W * 64, timeout=60)
        before = int(words[0, STEPS])
        os.kill(int(words[0, PID]), signal.SIGKILL)
        rng = np.random.default_rng(0)
        deadline = time.monotonic() + 20
        while pool.stats()["worker_restarts"] == 0 or words[0, STEPS] < before + 64:
            assert time.monotonic() < deadline
            batch = pool.sample(256, rng)  # notices the death; keeps sampling from both regions
            _float_fields_finite(batch)
            assert (batch["policy_version"] == 0).all() and (batch["episode_length"] >= 1).all()
            time.sleep(0.01)
    finally:
        pool.close()


# ---- non-finite data --------------------------------------------------------------------------
@pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")  # the serial policy acting on an Inf obs
@pytest.mark.parametrize("task,serial", [("toy_nan", False), ("toy_nan_noreset", True)],
                         ids=["reset-processes", "noreset-serial"])
def test_nonfinite_rows_are_zeroed_truncated_and_counted(task, serial):
    rounds = 3
    pool = _pool("toy_algo_nan", task=(task, {}), obs_dim=3, serial=serial).start()
    want = toy_nan_task.expected_rows(rounds * T, M, resettable=task == "toy_nan")
    assert want.any() and not want.all()
    try:
        for r in range(rounds):
            pool.publish(_weights(3, r), r)
            batch, _ = pool.collect(timeout=60)
            _float_fields_finite(batch)
            rows = np.tile(want[r * T : (r + 1) * T], (1, W))  # [T, W*M]: both workers follow the schedule
            np.testing.assert_array_equal(batch["truncated"], rows)  # episodes are 10k steps otherwise
            assert not batch["terminated"].any()
            for name in ("obs", "critic_obs", "action", "reward", "next_obs", "reward_terms", "log_prob"):
                assert (batch[name][rows] == 0).all(), name
            assert (batch["reward"][~rows] != 0).all()
        stats = pool.stats()
        assert stats["nonfinite_rows"] == W * int(want.sum())
        assert np.isfinite(stats["episode_return_mean"])
    finally:
        pool.close()


def test_nan_actions_from_the_policy_never_reach_the_batch():
    pool = _pool("toy_algo_nanact").start()
    want = np.stack([toy_algo_nanact.nan_envs(c, M) for c in range(2 * T)])
    try:
        for r in range(2):
            pool.publish(_weights(5, r), r)
            batch, _ = pool.collect(timeout=60)
            _float_fields_finite(batch)
            rows = np.tile(want[r * T : (r + 1) * T], (1, W))
            assert batch["truncated"][rows].all() and not batch["terminated"][rows].any()
            assert (batch["action"][rows] == 0).all() and (batch["log_prob"][rows] == 0).all()
            assert (batch["log_prob"][~rows] != 0).all()
        assert pool.stats()["nonfinite_rows"] == W * int(want.sum())
    finally:
        pool.close()


# ---- the replay env-step limit ----------------------------------------------------------------
def test_replay_workers_stop_at_the_step_limit():
    limit = 400
    pool = _pool("toy_algo_nan_replay", task=("toy_nan", {}), obs_dim=3, replay_capacity=1024,
                 max_env_steps=limit).start()
    words = _words(pool)
    try:
        pool.publish(_weights(3, 0), 0)
        _wait(pool.step_limit_reached, what="the step limit")
        time.sleep(0.3)
        steps = pool.env_steps()
        assert limit <= steps < limit + W * M  # each worker checks before every step
        beats = words[:, HEARTBEAT].copy()
        time.sleep(0.3)
        assert pool.env_steps() == steps and (words[:, HEARTBEAT] > beats).all()  # idle, alive
        # The NaN schedule again, through replay rows: nothing non-finite is ever sampled.
        per_worker = [int(words[w, STEPS]) // M for w in range(W)]
        assert pool.stats()["nonfinite_rows"] == sum(int(toy_nan_task.expected_rows(n, M, True).sum())
                                                     for n in per_worker)
        batch = pool.sample(2048, np.random.default_rng(0))
        _float_fields_finite(batch)
        assert batch["truncated"].any()
        pool.set_step_limit(2 * limit)
        _wait(lambda: pool.env_steps() >= 2 * limit, what="the raised limit")
        time.sleep(0.2)
        assert pool.env_steps() < 2 * limit + W * M
        t0 = time.monotonic()
        pool.close()
        assert time.monotonic() - t0 < 3  # capped workers still answer the stop flag
    finally:
        pool.close()
    with pytest.raises(ValueError, match="replay"):
        _pool("toy_algo", max_env_steps=10)


def test_trainer_replay_run_ends_at_its_budget(tmp_path):
    """Workers stop at the budget while the learner waits (warm-up here, a first jit compile in real
    runs) instead of running on; the restart and non-finite counters are logged."""
    from unilab_jax import algos
    from unilab_jax.config import apply_overrides
    from unilab_jax.training.trainer import RunConfig, Trainer

    module = algos.get("sac")
    config = apply_overrides(module.Config(), {"actor_hidden": (8,), "critic_hidden": (8,), "batch_size": 32,
                                               "learning_starts": 100_000, "replay_capacity": 100_000})
    run = RunConfig(algo="sac", task="cartpole_balance", num_workers=2, envs_per_worker=16, total_steps=2_000,
                    logdir=str(tmp_path / "sac"), eval_envs=2)
    summary = Trainer(run, module, config, {}).train()
    assert 2_000 <= summary["env_steps"] < 2_000 + 2 * 16
    rows = [json.loads(line) for line in open(tmp_path / "sac" / "metrics.jsonl")]
    logged = [r for r in rows if "perf/worker_restarts" in r]
    assert logged and all(r["perf/worker_restarts"] == 0 and r["perf/nonfinite_rows"] == 0 for r in logged)
