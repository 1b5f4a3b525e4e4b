"""Experiment scripts as a user runs them: subprocesses with tiny budgets."""

import glob
import json
import os
import subprocess
import sys

import pytest
from compile_options import fast_compile_env
from script_helpers import run_in_process

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _run(script, *args, timeout=600, env=None):
    return subprocess.run([sys.executable, os.path.join(ROOT, "experiments", script), *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout, env=env)


def test_ppo_go1_runs_and_resumes(tmp_path):
    logdir = str(tmp_path / "go1")
    short = "--task_config=episode_length=200"  # evaluations run whole episodes: keep them short
    # 10k + 10k env steps (7 updates of 1536 each run; 20k + 20k before): the resume and the metrics are what is
    # checked, and the collection was ~3.5 s of each run's ~10 s (the rest start-up, compile and the evaluation).
    first = _run("ppo_go1.py", "--total_steps=10000", "--num_workers=2", "--eval_envs=2", short, f"--logdir={logdir}")
    assert first.returncode == 0, first.stderr[-3000:]
    # The start-up milestones bench/time_to_target.py reads stay in the quiet launcher's log.
    assert "workers started" in first.stderr and "learner state ready" in first.stderr
    assert glob.glob(os.path.join(logdir, "events.out.tfevents.*"))
    steps = sorted(int(d) for d in os.listdir(os.path.join(logdir, "checkpoints")) if d.isdigit())
    assert steps and steps[-1] >= 10000
    second = _run("ppo_go1.py", "--total_steps=20000", "--num_workers=2", "--eval_envs=2", short, "--resume",
                  f"--logdir={logdir}")
    assert second.returncode == 0, second.stderr[-3000:]
    summary = json.load(open(os.path.join(logdir, "summary.json")))
    assert summary["env_steps"] >= 20000
    rows = [json.loads(line) for line in open(os.path.join(logdir, "metrics.jsonl"))]
    evals = [r for r in rows if "eval/return" in r]
    # Locomotion evaluations carry the walking metric (velocity tracking in m/s, fall rate in [0, 1]).
    assert evals and all(r["eval/tracking_error"] > 0 and 0 <= r["eval/fall_rate"] <= 1 for r in evals)
    # ... and the walking criterion's verdict (a 20k-step policy does not walk).
    assert all(r["eval/yaw_rate_error"] > 0 and r["eval/walking"] == 0.0 for r in evals)
    resumed = [r["step"] for r in rows[len(rows) // 2:] if "loss/policy_loss" in r]
    # The second run continues from the saved step: its first training row follows it directly.
    train_steps = [r["step"] for r in rows if "loss/policy_loss" in r]
    assert train_steps == sorted(train_steps) and len(set(train_steps)) == len(train_steps)
    assert resumed and min(s for s in train_steps if s > steps[-1]) == steps[-1] + 24 * 2 * 32
    # The clock goes on across the resume (the second process's start-up counted again): one run, timed as one.
    clock = [r["time/wall_s"] for r in rows if "time/wall_s" in r]
    assert clock == sorted(clock) and summary["wall_s"] > clock[0] + 1.0


def test_ppo_g1_track_runs_and_reports_the_tracking_metric(tmp_path):
    # Issue criterion: ppo_g1_track.py exits 0 on a tiny budget; its evaluation plays the clips from their start.
    logdir = str(tmp_path / "track")
    # 2 x 32 envs (auto sizing gives 1 x 1920 here: 46k steps before the first update, 37 s, 1.5 GB; exits 0 too).
    # A few updates: XLA compiles fast (tests/compile_options.py).
    out = _run("ppo_g1_track.py", "--total_steps=5000", "--num_workers=2", "--envs_per_worker=32", "--eval_envs=4",
               f"--logdir={logdir}", env=fast_compile_env())
    assert out.returncode == 0, out.stderr[-3000:]
    summary = json.load(open(os.path.join(logdir, "summary.json")))
    assert summary["env_steps"] >= 5000 and 0.0 <= summary["eval/clip_completion"] <= 1.0
    assert 0.0 < summary["eval/body_pos_error"] < 1.0  # metres, mean over the tracked bodies


@pytest.mark.parametrize("flag,message", [
    ("--num_workers=0", "--num_workers must be at least 1"),
    ("--platform=tpu", "--platform='tpu'"),
    ("--config=learning_rat=1", "unknown config key"),
    ("--task_config=no_such_key=1", "unknown config key"),
    ("--task=mars_rover", "registered tasks"),
    ("--task=gym:CartPole-v1", "action space Discrete(2) is not a Box"),
    ("--task=gym:NoSuchEnv-v0", "cannot be made"),
    ("--total_steps=-5", "--total_steps must be positive"),
    ("--utd_window=-1", "--utd_window must be >= 0"),
    ("--utd_window=4096", "--utd_window needs an off-policy algorithm"),
    ("--pin_cpus=-2", "--pin_cpus must be -1 (off)"),
])
def test_invalid_flags_fail_before_workers_start(tmp_path, flag, message):
    out = run_in_process("ppo_cartpole.py", flag, f"--logdir={tmp_path / 'x'}")
    assert out.returncode == 2, out.stderr[-2000:]
    assert message in out.stderr
    assert "Traceback" not in out.stderr


@pytest.mark.parametrize("script,flag,message", [
    ("sac_cartpole.py", "--config=batch_size=-5", "SACConfig: batch_size, updates_per_call and publish_every must"),
    ("ppo_cartpole.py", "--config=gamma=2.5", "PPOConfig: need 0 <= gamma <= 1"),
    ("sac_cartpole.py", "--config=gamma=2.5", "SACConfig: need 0 <= gamma <= 1"),
    ("sac_cartpole.py", "--config=utd=1e999", "config key 'utd': must be a finite number, got inf"),
    ("sac_cartpole.py", "--config=tau=nan", "config key 'tau': must be a finite number, got 'nan'"),
    ("ppo_cartpole.py", "--config=actor_hidden=(64, -1)", "hidden layer sizes must be positive"),
    ("ppo_cartpole.py", "--task_config=ctrl_dt=-inf", "config key 'ctrl_dt': must be a finite number"),
    ("ppo_cartpole.py", "--task_config=dr_motor_strength=(1.0, 1e999)", "'dr_motor_strength': must be a finite"),
    ("ppo_cartpole.py", "--task_config=episode_length=-5", "episode_length must be positive, got -5"),
    ("ppo_cartpole.py", "--task_config=ctrl_dt=-0.02", "ctrl_dt -0.02 must be a multiple of sim_dt"),  # the task's
    ("sac_cartpole.py", "--config=replay_capacity=10", "exceed the replay capacity (128 transitions over 2 workers)"),
])
def test_bad_config_values_exit_2(tmp_path, script, flag, message):
    # Issue 34: every config validation (the algorithm config's own, non-finite numbers) is exit 2 and a message.
    out = run_in_process(script, flag, f"--logdir={tmp_path / 'x'}")
    assert out.returncode == 2, out.stderr[-2000:]
    assert message in out.stderr
    assert "Traceback" not in out.stderr


def test_resume_without_checkpoint_is_an_error(tmp_path):
    # A real process (the tables above run the script's main in the test process): exit status 2, no traceback.
    out = _run("ppo_cartpole.py", "--resume", f"--logdir={tmp_path / 'empty'}", timeout=120)
    assert out.returncode == 2 and "no checkpoints" in out.stderr and "Traceback" not in out.stderr


def test_fastsac_g1_trained_on_mlx_resumes_on_jax(tmp_path):
    # Issue criterion: fastsac_g1.py runs with --platform=mlx and its checkpoint restores with --platform=jax.
    logdir = str(tmp_path / "g1")
    # Hidden layers of 64 (the recipe's 512-256-128 actor and 1024-512-256 critics made the first MLX update call
    # ~12 s of the mlx run's 18 s on the 2-core VM; with 64-64: 8.5 s): what crosses platforms is the checkpoint's
    # layout (the same tree of the recipe's C51 critics, LayerNorm and temperature), not its width.
    small = ["--num_workers=2", "--config=learning_starts=2048", "--config=batch_size=256", "--eval_envs=2",
             "--config=actor_hidden=(64, 64)", "--config=critic_hidden=(64, 64)",
             "--task_config=episode_length=200", f"--logdir={logdir}"]
    first = _run("fastsac_g1.py", "--platform=mlx", "--total_steps=5000", *small)  # MLX: XLA_FLAGS play no part
    assert first.returncode == 0, first.stderr[-3000:]
    done = json.load(open(os.path.join(logdir, "summary.json")))
    assert done["updates"] >= 1 and os.listdir(os.path.join(logdir, "checkpoints"))
    # The resumed rings start empty (no --replay_dir) and the pool caps env steps at the budget: 2048 steps refill
    # learning_starts, then 1024 more make one call of 8 gradient steps (utd 8/1024); 5000 leave room for several.
    second = _run("fastsac_g1.py", "--platform=jax", "--resume", f"--total_steps={done['env_steps'] + 5000}", *small,
                  env=fast_compile_env())  # a few learner calls: XLA compiles fast (tests/compile_options.py)
    assert second.returncode == 0, second.stderr[-3000:]
    resumed = json.load(open(os.path.join(logdir, "summary.json")))
    assert resumed["updates"] > done["updates"] and resumed["env_steps"] >= done["env_steps"] + 5000
