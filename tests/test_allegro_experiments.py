"""experiments/ppo_allegro_rotate.py and hora_allegro.py as a user runs them: subprocesses with tiny budgets."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

from compile_options import fast_compile_env

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# One worker with 4 envs, 8-step slots, 20-step episodes, small networks: every stage is one or two updates.
TINY = ["--num_workers=1", "--envs_per_worker=4", "--eval_envs=2", "--task_config=episode_length=20",
        "--config=horizon=8", "--config=actor_hidden=(32,)", "--config=critic_hidden=(32,)"]
METRICS = ("return", "rotation_rate", "time_to_fall", "rotate_reward")


def _run(script, *args, timeout=600):
    # XLA compiles fast (tests/compile_options.py): these budgets make one or two updates, nearly all compile time.
    return subprocess.run([sys.executable, os.path.join(ROOT, "experiments", script), *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout, env=fast_compile_env())


def test_ppo_allegro_rotate_logs_the_rotation_metrics(tmp_path):
    logdir = str(tmp_path / "ppo")
    out = _run("ppo_allegro_rotate.py", "--total_steps=64", *TINY, f"--logdir={logdir}")
    assert out.returncode == 0, out.stderr[-3000:]
    summary = json.load(open(os.path.join(logdir, "summary.json")))
    for k in METRICS:
        assert math.isfinite(summary[f"eval/{k}"]), summary
    assert 0.0 <= summary["eval/time_to_fall"] <= 1.0


def test_hora_allegro_compares_student_and_teacher_on_rotation_rate(tmp_path):
    logdir = str(tmp_path / "hora")
    out = _run("hora_allegro.py", "--teacher_steps=32", "--student_steps=32", *TINY, "--config=encoder_hidden=(16,)",
               "--student_config=horizon=8", f"--logdir={logdir}")
    assert out.returncode == 0, out.stderr[-3000:]
    summary = json.load(open(os.path.join(logdir, "hora_summary.json")))
    assert summary["compared_metric"] == "rotation_rate"
    for who in ("teacher", "student"):
        for k in METRICS:
            assert math.isfinite(summary[f"{who}_eval_{k}"]), summary
    t, s = summary["teacher_eval_rotation_rate"], summary["student_eval_rotation_rate"]
    if t > 0:
        assert summary["student_to_teacher"] == s / t
    else:  # an untrained teacher may not rotate the object at all: no ratio
        assert math.isnan(summary["student_to_teacher"])
