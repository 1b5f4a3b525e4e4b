"""The replay rings kept across an orderly stop (``training/ring_snapshot.py``): a run that stops in order writes
``LOGDIR/replay_rings``, and ``--resume`` copies it into the new rings before any worker starts, with the device
mirror on (as the GPU recipes run); a snapshot of another layout, a damaged or incomplete one, or none, leaves the
rings empty with the reason logged.

Serial runs of a tiny SAC on cart-pole, 2 workers x 16 envs with 2048-row rings: the first (which compiles) ~4 s,
the others well under a second. A run whose ``total_steps`` is its checkpoint's takes no env step: the snapshot it
writes at its stop is then exactly the rings it started with.
"""

from __future__ import annotations

import json
import logging
import os
import shutil

import numpy as np
import pytest

import unilab_jax
from unilab_jax import algos
from unilab_jax.config import apply_overrides
from unilab_jax.training.ring_snapshot import FOLDER
from unilab_jax.training.trainer import RunConfig, Trainer

TINY_SAC = {"actor_hidden": (8,), "critic_hidden": (8,), "batch_size": 32, "updates_per_call": 2, "publish_every": 4,
            "learning_starts": 256, "replay_capacity": 4_096, "utd": 0.05}
STOPPED_AT = 1_024  # env steps of the first run: 512 rows in each worker's ring


def _trainer(logdir, total_steps, resume=False, envs_per_worker=16, **config):
    module = algos.get("sac")
    run = RunConfig(algo="sac", task="cartpole_balance", num_workers=2, envs_per_worker=envs_per_worker,
                    total_steps=total_steps, seed=0, logdir=str(logdir), serial=True, eval_envs=2, resume=resume,
                    replay_on_device="on", keep_replay=True)
    return Trainer(run, module, apply_overrides(module.Config(), {**TINY_SAC, **config}), {})


def _run(logdir, total_steps, resume=False, envs_per_worker=16, **config):
    return _trainer(logdir, total_steps, resume, envs_per_worker, **config).train()


def _snapshot(logdir):
    """(layout.json, {field: [workers, capacity, ...]}) of the rings kept in ``logdir``."""
    folder = logdir / FOLDER
    doc = json.loads((folder / "layout.json").read_text())
    return doc, {name: np.load(folder / f"{name}.npy") for name, _, _ in doc["fields"]}


@pytest.fixture(scope="module")
def stopped(tmp_path_factory):
    """The log directory of a run that ended in order at ``STOPPED_AT`` env steps (each test resumes a copy)."""
    logdir = tmp_path_factory.mktemp("rings") / "run"
    _run(logdir, STOPPED_AT)
    return logdir


@pytest.fixture
def resumable(stopped, tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="unilab_jax.training.ring_snapshot")
    logdir = tmp_path / "run"
    shutil.copytree(stopped, logdir)
    return logdir


def test_a_resumed_run_goes_on_with_the_rings_it_stopped_with(resumable, caplog):
    saved_doc, saved = _snapshot(resumable)
    assert saved_doc["counts"] == [512, 512] and saved_doc["env_steps"] == STOPPED_AT
    summary = _run(resumable, 1_300, resume=True)
    assert "1024 transitions restored" in caplog.text
    # The device mirror's first sync uploaded the restored rows with the new ones.
    rows = [json.loads(line) for line in open(os.path.join(summary["logdir"], "metrics.jsonl"))]
    first = next(r for r in rows if r["step"] > STOPPED_AT and "perf/replay_upload_rows" in r)
    assert first["perf/replay_upload_rows"] >= 1_024
    # Learning went on at once: with empty rings the run warms up again (learning_starts=256) and its 288 env
    # steps make no update. The ratio counts the gradient steps since learning started, the first run's too.
    assert summary["updates"] > 18 and "warning" not in summary
    # The workers wrote on at their cursors: the rows they kept are the saved ones, the counts went on from there.
    doc, after = _snapshot(resumable)
    new = (summary["env_steps"] - STOPPED_AT) // 2
    assert doc["counts"] == [512 + new, 512 + new] and doc["env_steps"] == summary["env_steps"]
    for name, region in saved.items():
        assert region[:, :512].tobytes() == after[name][:, :512].tobytes(), name


def test_a_run_stopped_by_a_signal_keeps_its_rings(tmp_path):
    """SIGINT and SIGTERM set the trainer's stop flag (``threads.stop_on_signals``): set here after the 4th update."""
    trainer = _trainer(tmp_path / "run", 100_000)
    dispatch, calls = trainer._dispatch, []

    def stopping(state, batch):
        calls.append(1)
        if len(calls) == 4:
            trainer._stop.set()
        return dispatch(state, batch)

    trainer._dispatch = stopping
    summary = trainer.train()
    assert summary["interrupted"] and summary["env_steps"] < 2 * 2_048
    doc, _ = _snapshot(tmp_path / "run")
    assert sum(doc["counts"]) == doc["env_steps"] == summary["env_steps"]


@pytest.mark.parametrize(("change", "reason"), [
    ({"envs_per_worker": 8}, "envs_per_worker differs: saved 16, this run's 8"),
    ({"replay_capacity": 2_048}, "capacity differs: saved 2048, this run's 1024"),
], ids=["envs_per_worker", "capacity"])
def test_rings_of_another_layout_are_not_restored(resumable, caplog, change, reason):
    _run(resumable, STOPPED_AT, resume=True, **change)
    assert reason in caplog.text and "the rings start empty" in caplog.text
    doc, _ = _snapshot(resumable)
    assert doc["counts"] == [0, 0]


def _truncate(folder):
    with open(folder / "obs.npy", "r+b") as f:
        f.truncate(os.path.getsize(folder / "obs.npy") // 2)


@pytest.mark.parametrize(("damage", "reason"), [
    (_truncate, "obs.npy cannot be read"),
    (lambda folder: (folder / "layout.json").unlink(), "layout.json cannot be read"),
    (lambda folder: (folder / "layout.json").write_text('{"format": "unilab-replay-rings", "vers'),
     "layout.json cannot be read"),
    (shutil.rmtree, "no snapshot in"),
], ids=["truncated_npy", "no_layout", "partial_layout", "no_snapshot"])
def test_a_damaged_incomplete_or_missing_snapshot_leaves_the_rings_empty(resumable, caplog, damage, reason):
    damage(resumable / FOLDER)
    summary = _run(resumable, STOPPED_AT, resume=True)
    assert reason in caplog.text and "the rings start empty" in caplog.text
    assert summary["env_steps"] == STOPPED_AT
    doc, _ = _snapshot(resumable)
    assert doc["counts"] == [0, 0]



def test_keep_replay_off_or_a_replay_store_keep_no_rings(tmp_path):
    """By default (``keep_replay`` off: a run does not write gigabytes at each stop unless asked) and with
    ``--replay_dir`` (whose store keeps the replay instead) no rings are kept; ``keep_replay=True`` keeps them (the
    command line's checks and flags, through ``unilab_jax.train``)."""
    kept = {}
    store = {"replay_dir": str(tmp_path / "store"), "replay_on_device": "off"}
    for name, option in (("plain", {}), ("on", {"keep_replay": True}), ("store", {**store, "keep_replay": True})):
        summary = unilab_jax.train("sac", "cartpole_balance", logdir=str(tmp_path / name), total_steps=512,
                                   config=TINY_SAC, num_workers=2, envs_per_worker=16, serial=True, eval_envs=2,
                                   **{"replay_on_device": "on", **option})
        assert summary["env_steps"] == 512
        kept[name] = (tmp_path / name / FOLDER).is_dir()
    assert kept == {"plain": False, "on": True, "store": False}
