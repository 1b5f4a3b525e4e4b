"""Crash recovery of off-policy runs with the persistent replay store (``--replay_dir``).

* Resume exactness (serial mode, the real Trainer): N+M updates straight == N, checkpoint,
  restore, M, bitwise, for every leaf of the learner state and the sampler's bookkeeping.
* ``kill -9`` of a learner (``experiments/sac_cartpole.py``) at a random moment after a checkpoint;
  ``--resume`` finishes, its step counter and buffer size go on from the checkpoint, and the
  killed run's shared memory is gone.
* A diverging learner (non-finite losses) stops the run with ``LearningDiverged``, its state is not
  checkpointed, and the summary says why the run ended.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from compile_options import fast_compile_env

from unilab_jax import algos
from unilab_jax.checkpoint import Checkpointer
from unilab_jax.config import apply_overrides
from unilab_jax.runtime.replay_store import ReplayStore
from unilab_jax.runtime.shm import cleanup_stale, list_segments
from unilab_jax.training.trainer import LearningDiverged, RunConfig, Trainer

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TINY_SAC = {"actor_hidden": (8,), "critic_hidden": (8,), "batch_size": 32, "updates_per_call": 2, "publish_every": 4,
            "learning_starts": 256, "replay_capacity": 4_096, "utd": 0.05}


def _serial_run(logdir, total_steps, resume=False):
    module = algos.get("sac")
    run = RunConfig(algo="sac", task="cartpole_balance", num_workers=2, envs_per_worker=16, total_steps=total_steps,
                    seed=0, logdir=str(logdir), serial=True, eval_envs=2, checkpoint_every=1_024, resume=resume,
                    replay_dir=str(logdir / "replay"), replay_hot_fraction=0.0, replay_chunk_rows=16_384)
    return Trainer(run, module, apply_overrides(module.Config(), TINY_SAC), {}).train()


def test_serial_resume_is_exact(tmp_path):
    """Run A trains straight to 1824 env steps (38 updates), checkpointing at 1024 (18 updates); run B
    stops at 1024 and resumes to 1824. Their checkpoints at 1024 and at the end must be identical.

    Compared: every leaf of the SAC state (actor, critics, target critics, their Adam moments and
    counts, log_alpha and its optimizer, the obs / critic-obs / reward normalizer statistics, the JAX
    RNG key, the step count), the counters (env steps, updates = the sampler's RNG index, weight
    version), the sampler's ratio bookkeeping and publish phase, and the store's cursor; plus the
    store's rows up to the checkpoint.

    Not compared: the workers' env state. Tasks expose no state to save, so the resumed run builds
    fresh workers (seeds offset by the update count) whose transitions differ from run A's after the
    checkpoint. What keeps the comparison exact anyway: every minibatch comes from the disk tier
    (``replay_hot_fraction=0``) and the M updates collect fewer transitions than a chunk (16384
    rows), so after the checkpoint both runs sample the same committed rows; with a hot fraction
    of 0.5 the states part within the M updates (checked by hand when this test was written).
    """
    a, b = tmp_path / "a", tmp_path / "b"
    straight = _serial_run(a, 1_800)
    first = _serial_run(b, 1_024)
    with pytest.raises(ValueError, match="pass --resume"):  # a fresh run never adopts an earlier run's store
        _serial_run(b, 1_800)
    resumed = _serial_run(b, 1_800, resume=True)
    assert (first["updates"], straight["updates"], resumed["updates"]) == (18, 38, 38)
    ck_a, ck_b = Checkpointer(str(a / "checkpoints")), Checkpointer(str(b / "checkpoints"))
    assert ck_a.all_steps() == ck_b.all_steps() == [1_024, 1_824]
    states = {}
    for step in (1_024, 1_824):
        assert ck_a.verify(step) and ck_b.verify(step)  # the trainer's saves carry digests (issue 34), resumed too
        _, va, ma = ck_a.read(step)
        _, vb, mb = ck_b.read(step)
        assert sorted(va) == sorted(vb) and any(k.startswith("actor_opt/") for k in va) and "key" in va
        differ = [k for k in va if va[k].dtype != vb[k].dtype or not np.array_equal(va[k], vb[k])]
        assert not differ, f"step {step}: leaves differ after resume: {differ}"
        assert ma["counters"] == mb["counters"]
        ra, rb = ma["replay"], mb["replay"]
        assert ra.pop("store_dir") != rb.pop("store_dir") and ra == rb
        states[step] = va
    assert not np.array_equal(states[1_024]["actor/0/w"], states[1_824]["actor/0/w"])  # the M updates moved it
    assert ma["replay"]["store_committed"] == 1_824 and ma["counters"]["updates"] == 38
    ck_a.close()
    ck_b.close()
    with ReplayStore(str(a / "replay")) as sa, ReplayStore(str(b / "replay")) as sb:
        ra, rb = sa.read(0, 1_024), sb.read(0, 1_024)
        assert all(np.array_equal(ra[k], rb[k]) for k in ra)


def _checkpoint_steps(ckpt_dir):
    return sorted(int(d) for d in os.listdir(ckpt_dir) if d.isdigit()) if os.path.isdir(ckpt_dir) else []


def _script(logdir, *extra):
    return [sys.executable, os.path.join(ROOT, "experiments", "sac_cartpole.py"), f"--logdir={logdir}",
            f"--replay_dir={logdir}/replay", "--replay_chunk_rows=4096", "--checkpoint_every=10000", "--num_workers=2",
            "--envs_per_worker=16", "--eval_envs=2", *extra]


def test_sigkill_of_the_learner_then_resume_continues(tmp_path):
    logdir = str(tmp_path / "run")
    ckpt_dir = os.path.join(logdir, "checkpoints")
    proc = subprocess.Popen(_script(logdir, "--total_steps=5000000"), cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, env=fast_compile_env())
    try:
        deadline = time.monotonic() + 120
        while not _checkpoint_steps(ckpt_dir):  # the first checkpoint comes after the first update's compile
            assert proc.poll() is None, proc.stderr.read()[-3000:]
            assert time.monotonic() < deadline, "no checkpoint within 120 s"
            time.sleep(0.05)
        time.sleep(random.uniform(0.0, 1.0))
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        ckpt = Checkpointer(ckpt_dir)
        step, _, meta = ckpt.read()
        ckpt.close()
        saved = meta["replay"]
        assert saved["store_size"] >= 5_000 and meta["counters"]["updates"] >= 1  # learning had started
        n_rows = sum(1 for _ in open(os.path.join(logdir, "metrics.jsonl")))
        out = subprocess.run(_script(logdir, "--resume", f"--total_steps={step + 30_000}"), cwd=ROOT,
                             capture_output=True, text=True, timeout=300, env=fast_compile_env())
        assert out.returncode == 0, out.stderr[-3000:]
        summary = json.load(open(os.path.join(logdir, "summary.json")))
        assert summary["env_steps"] >= step + 30_000 and not summary["interrupted"]
        assert summary["updates"] > meta["counters"]["updates"]
        rows = [json.loads(line) for line in open(os.path.join(logdir, "metrics.jsonl"))][n_rows:]
        train = [r for r in rows if "replay/size" in r]
        # The step counter continues from the checkpoint (not from 0, not from where the kill was) ...
        assert step < train[0]["step"] <= step + 30_000 + 2 * 16
        # ... and so does the buffer: the store holds at least what the checkpoint recorded, at once.
        assert train[0]["replay/size_disk"] >= saved["store_size"]
        assert train[0]["replay/disk_committed"] >= saved["store_committed"]
        assert any("loss/critic_loss" in r for r in train)
        assert not [n for n in os.listdir(os.path.join(logdir, "replay")) if n.endswith(".tmp")]
        with ReplayStore(os.path.join(logdir, "replay")) as store:
            assert store.committed >= saved["store_committed"] + 30_000
        # The killed learner's segments were removed (by the resource tracker or the resumed run).
        assert not [n for n in list_segments() if n.startswith(f"unilab_{proc.pid}_")]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        cleanup_stale()


def test_replay_dir_is_refused_for_trajectory_algorithms(tmp_path):
    out = subprocess.run([sys.executable, os.path.join(ROOT, "experiments", "ppo_cartpole.py"),
                          f"--replay_dir={tmp_path / 'r'}", f"--logdir={tmp_path / 'x'}"], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and "does not use a replay buffer" in out.stderr


def test_diverging_learner_stops_without_saving_the_diverged_state(tmp_path):
    """Learning rates of 1e30 make SAC's first update non-finite (Adam moves each weight by about the
    learning rate, so the call's second gradient step overflows). The run must raise LearningDiverged at
    that update instead of training on and publishing NaN weights, skip the end-of-run checkpoint of the
    diverged state (without the guard the run trains on and saves it), and write a summary naming the
    non-finite losses."""
    module = algos.get("sac")
    run = RunConfig(algo="sac", task="cartpole_balance", num_workers=2, envs_per_worker=16, total_steps=20_000,
                    seed=0, logdir=str(tmp_path), serial=True, eval_envs=2)
    cfg = apply_overrides(module.Config(), {**TINY_SAC, "actor_learning_rate": 1e30, "critic_learning_rate": 1e30})
    with pytest.raises(LearningDiverged, match="non-finite loss/.* at update 1 ") as info:
        Trainer(run, module, cfg, {}).train()
    summary = json.load(open(tmp_path / "summary.json"))
    assert summary["interrupted"] and summary["updates"] == 1 and "non-finite" in summary["diverged"]
    assert 0 < summary["env_steps"] < 20_000
    assert info.value.names and all(name.startswith("loss/") for name in info.value.names)
    ckpt = Checkpointer(str(tmp_path / "checkpoints"))
    assert ckpt.all_steps() == []
    ckpt.close()
