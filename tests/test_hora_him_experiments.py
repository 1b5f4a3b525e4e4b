"""experiments/hora_go1.py and him_ppo_go1.py as a user runs them: subprocesses with tiny Go1 budgets."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import pytest
from compile_options import fast_compile_env
from script_helpers import run_in_process

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# One worker with 4 envs, 8-step slots, 20-step episodes, small networks: every stage is one or two updates.
TINY = ["--num_workers=1", "--envs_per_worker=4", "--eval_envs=1", "--task_config=episode_length=20",
        "--config=horizon=8", "--config=actor_hidden=(32,)", "--config=critic_hidden=(32,)"]


def _run(script, *args, timeout=600):
    # XLA compiles fast (tests/compile_options.py): these budgets make one or two updates, nearly all compile time.
    return subprocess.run([sys.executable, os.path.join(ROOT, "experiments", script), *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout, env=fast_compile_env())


def _rows(path):
    with open(path) as f:
        return [json.loads(line) for line in f]


def test_hora_go1_runs_both_stages_and_resumes_the_student(tmp_path):
    logdir = str(tmp_path / "hora")
    args = [*TINY, "--config=encoder_hidden=(16,)", "--student_config=horizon=8", f"--logdir={logdir}"]
    first = _run("hora_go1.py", "--teacher_steps=32", "--student_steps=32", *args)
    assert first.returncode == 0, first.stderr[-3000:]
    summary = json.load(open(os.path.join(logdir, "hora_summary.json")))
    for key in ("teacher_eval_return", "student_eval_return", "student_to_teacher", "z_mse_first", "z_mse_ratio_last"):
        assert math.isfinite(summary[key]), summary
    teacher_rows = _rows(os.path.join(logdir, "teacher", "metrics.jsonl"))
    assert any("loss/policy_loss" in r for r in teacher_rows)
    assert any("hora/student_to_teacher" in r for r in _rows(os.path.join(logdir, "student", "metrics.jsonl")))
    # The teacher's budget is done: --resume goes straight to the student, which continues from its step.
    second = _run("hora_go1.py", "--teacher_steps=32", "--student_steps=64", "--resume", *args)
    assert second.returncode == 0, second.stderr[-3000:]
    assert "teacher: finished run found" in second.stdout
    assert len(_rows(os.path.join(logdir, "teacher", "metrics.jsonl"))) == len(teacher_rows)
    student = json.load(open(os.path.join(logdir, "student", "summary.json")))
    assert student["env_steps"] >= 64 and student["updates"] == 2
    z_steps = [r["step"] for r in _rows(os.path.join(logdir, "student", "metrics.jsonl")) if "loss/z_mse" in r]
    assert z_steps == [32, 64]


def test_him_ppo_go1_runs(tmp_path):
    logdir = str(tmp_path / "him")
    out = _run("him_ppo_go1.py", "--total_steps=32", "--config=estimator_hidden=(16,)", *TINY, f"--logdir={logdir}")
    assert out.returncode == 0, out.stderr[-3000:]
    rows = [r for r in _rows(os.path.join(logdir, "metrics.jsonl")) if "loss/velocity_loss" in r]
    assert rows and all(math.isfinite(r["loss/swap_loss"]) and math.isfinite(r["loss/policy_loss"]) for r in rows)


@pytest.mark.parametrize("script,flag,message", [
    ("hora_go1.py", "--platform=mlx", "hora_teacher has a learner for --platform=jax only"),
    ("him_ppo_go1.py", "--platform=mlx", "him_ppo has a learner for --platform=jax only"),
    ("hora_go1.py", "--total_steps=5", "use --teacher_steps and --student_steps"),
    ("hora_go1.py", "--history_len=20", "too short for conv_kernels"),
    ("hora_go1.py", "--resume", "no checkpoints under"),
    ("him_ppo_go1.py", "--task_config=history_extrinsics=True", "history_extrinsics=False"),
])
def test_bad_flags_fail_before_workers_start(tmp_path, script, flag, message):
    # In this process (tests/script_helpers.py); the test below checks a real process's exit status.
    out = run_in_process(script, flag, f"--logdir={tmp_path / 'x'}")
    assert out.returncode == 2, out.stderr[-2000:]
    assert message in out.stderr and "Traceback" not in out.stderr


def test_bad_flag_fails_in_a_real_process(tmp_path):
    out = _run("hora_go1.py", "--resume", f"--logdir={tmp_path / 'x'}", timeout=120)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "no checkpoints under" in out.stderr and "Traceback" not in out.stderr
