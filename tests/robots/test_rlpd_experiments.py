"""RLPD and SAC on peg insertion through robot servers: the experiment command, its flag checks."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from unilab_jax.runtime.replay_store import ReplayStore

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _script(name: str, *args: str, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, os.path.join(ROOT, "experiments", name), *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def test_rlpd_franka_peg_records_demos_and_trains(tmp_path):
    logdir = tmp_path / "run"
    out = _script("rlpd_franka_peg.py", "--speed=20", "--total_steps=2000", f"--logdir={logdir}", timeout=400)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "demonstrations: 20 episodes (20 successful" in out.stdout
    with ReplayStore(str(logdir / "demos")) as store:
        rows = store.read(store.first_row, store.committed)
    assert rows["success"].all() and len(set(rows["episode"].tolist())) == 20
    metrics = [json.loads(line) for line in open(logdir / "metrics.jsonl")]
    prior_rows = [r["perf/prior_rows"] for r in metrics if "perf/prior_rows" in r]
    assert prior_rows and set(prior_rows) == {64.0}  # half of each batch of 128 from the demonstrations
    assert any("loss/q_std" in r for r in metrics)  # the ensemble's spread: RLPD's critic ran
    summary = json.load(open(logdir / "summary.json"))
    assert summary["env_steps"] >= 2000 and not summary["interrupted"]
    assert 0.0 <= summary["eval/success_rate"] <= 1.0 and np.isfinite(summary["eval/return"])
    # robot time at speed 1: 2000 steps at 10 Hz plus the demonstrations' own steps
    assert summary["robot_s"] == pytest.approx(200.0 + len(rows["reward"]) / 10.0, abs=0.2)


@pytest.mark.parametrize("script,args,message", [
    ("sac_franka_peg.py", ["--demos=/nonexistent"], "learns without prior data"),
    ("rlpd_franka_peg.py", ["--demos=/nonexistent"], "no replay store there"),
    ("rlpd_franka_peg.py", ["--eval_every=100"], "evaluation needs 1 more"),
    ("rlpd_franka_peg.py", ["--config", "prior_fraction=1.0"], "prior_fraction must be in [0, 1)"),
])
def test_bad_flags_exit_2_before_anything_starts(tmp_path, script, args, message):
    out = _script(script, *args, f"--logdir={tmp_path / 'x'}", timeout=120)
    assert out.returncode == 2, out.stderr[-2000:]
    assert message in out.stderr and "Traceback" not in out.stderr
