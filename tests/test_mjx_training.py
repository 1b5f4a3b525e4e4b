"""GPU-resident training on MJX, run tiny on the CPU: PPO and FastSAC loops end to end, metrics written, the
training call traced once; flag validation of the MJX experiment scripts."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from compile_options import FAST_COMPILE
from script_helpers import run_in_process

from unilab_jax import algos
from unilab_jax.apps import cli
from unilab_jax.config import apply_overrides
from unilab_jax.training.mjx import MjxRunConfig, OffPolicyMjxTrainer, PPOMjxTrainer, make_trainer

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OPTS = FAST_COMPILE
TASK = {"noise_level": 0.0, "episode_length": 20}  # the env of tests/tasks/test_mjx_parity.py (compiled once)
M = 8


def _rows(logdir):
    return [json.loads(line) for line in open(os.path.join(logdir, "metrics.jsonl"))]


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory):
    logdir = str(tmp_path_factory.mktemp("ppo_mjx"))
    cfg = apply_overrides(algos.get("ppo").Config(), {"actor_hidden": (32,), "critic_hidden": (32,), "horizon": 12,
                                                      "num_epochs": 2, "num_minibatches": 2, "init_log_std": -1.0})
    run = MjxRunConfig(algo="ppo", task="go1_joystick_flat", num_envs=M, total_steps=2 * 12 * M, seed=0,
                       logdir=logdir, eval_every=12 * M, eval_envs=M)
    trainer = make_trainer(run, algos.get("ppo"), cfg, TASK, compiler_options=OPTS)
    return trainer, trainer.train(), _rows(logdir)


def test_ppo_mjx_trains_and_logs(ppo_run, capsys):
    trainer, summary, rows = ppo_run
    cli.report(summary)  # what the MJX experiment scripts print at the end (a run without checkpoints)
    assert f"logs: {summary['logdir']}" in capsys.readouterr().out
    assert isinstance(trainer, PPOMjxTrainer)
    assert summary["env_steps"] == 2 * 12 * M and summary["stopped_by"] == "total_steps"
    train = [r for r in rows if "loss/policy_loss" in r]
    assert [r["step"] for r in train] == [12 * M, 24 * M]
    for r in train:
        assert all(math.isfinite(r[k]) for k in ("loss/value_loss", "loss/kl", "loss/entropy", "time/wall_s"))
        assert r["perf/env_steps_per_s"] > 0 and "reward/tracking_lin_vel" in r
    assert "perf/first_call_s" in train[0]
    # 24 steps of 20-step episodes: every env's first episode ended (truncated at least) and was logged.
    assert any("episode/return" in r for r in train)
    evals = [r for r in rows if "eval/return" in r]
    assert [r["step"] for r in evals] == [12 * M, 24 * M]  # periodic; none repeated at the end
    for r in evals:
        assert r["eval/return"] >= 0.0 and 0 < r["eval/episode_length"] <= 20 and 0 <= r["eval/fall_rate"] <= 1
        # The walking metric over the same episodes: an untrained policy is far from the criterion.
        assert r["eval/tracking_error"] > 0.05 and r["eval/yaw_rate_error"] > 0.05 and r["eval/walking"] == 0.0
        assert r["eval/train_wall_s"] <= r["eval/wall_s"] <= r["eval/done_wall_s"]
    assert evals[1]["eval/train_wall_s"] < evals[1]["eval/wall_s"]  # the first evaluation's time is excluded
    assert trainer._call._cache_size() == 1  # one trace for every call
    assert os.path.exists(os.path.join(summary["logdir"], "summary.json"))
    assert any(f.startswith("events.out.tfevents") for f in os.listdir(summary["logdir"]))


@pytest.fixture(scope="module")
def fastsac_run(tmp_path_factory):
    logdir = str(tmp_path_factory.mktemp("fastsac_mjx"))
    cfg = apply_overrides(algos.get("fastsac").Config(), {
        "actor_hidden": (32,), "critic_hidden": (32,), "num_atoms": 11, "batch_size": 16, "updates_per_call": 2,
        "utd": 0.5, "replay_capacity": 40, "learning_starts": 24, "v_min": -0.5, "v_max": 1.5})
    run = MjxRunConfig(algo="fastsac", task="go1_joystick_flat", num_envs=M, total_steps=48, seed=1,
                       logdir=logdir, eval_every=0, eval_envs=M, iterations_per_call=3)
    trainer = make_trainer(run, algos.get("fastsac"), cfg, TASK, compiler_options=OPTS)
    return trainer, trainer.train(), _rows(logdir)


def test_fastsac_mjx_fills_replay_and_learns(fastsac_run):
    trainer, summary, rows = fastsac_run
    assert isinstance(trainer, OffPolicyMjxTrainer)
    # utd 0.5 x 8 envs = 4 gradient steps per env step = 2 learner calls of 2 steps; capacity 40 -> 5 rows of 8.
    assert (trainer.env_steps_per_iter, trainer.updates_per_iter, trainer.capacity) == (1, 2, 40)
    train = [r for r in rows if "perf/grad_steps" in r]
    assert [r["step"] for r in train] == [24, 48] and summary["env_steps"] == 48
    # First call: 24 transitions, learning starts once 24 are in (the third iteration's update).
    assert train[0]["perf/grad_steps"] == 4 and train[1]["perf/grad_steps"] == 12
    assert math.isclose(train[1]["perf/utd"], 0.5)
    assert all(math.isfinite(train[1][k]) for k in ("loss/critic_loss", "loss/actor_loss", "loss/alpha"))
    ring = trainer.final_carry[2]
    assert int(ring.size) == 40 and int(ring.ptr) == 48 % 40
    obs = np.asarray(ring.data["obs"])
    assert np.isfinite(obs).all() and np.abs(obs).sum(axis=1).min() > 0  # every row written
    evals = [r for r in rows if "eval/return" in r]
    assert len(evals) == 1 and evals[0]["step"] == 48  # the final evaluation (no periodic ones)
    assert trainer._call._cache_size() == 1


def test_mjx_trainer_rejects_async_algorithms():
    run = MjxRunConfig(algo="appo", task="go1_joystick_flat", num_envs=M, eval_envs=M)
    with pytest.raises(ValueError, match="no MJX trainer"):
        make_trainer(run, algos.get("appo"), algos.get("appo").Config(), TASK, compiler_options=OPTS)


@pytest.mark.parametrize("flag,message", [
    ("--num_workers=4", "--num_workers is a flag of the CPU-worker runtime"),
    ("--task=cartpole_balance", "tasks with an MJX variant"),
    ("--wandb_project=x", "MJX loop logs to TensorBoard"),
    ("--config=batch_size=-1", "batch_size"),
])
def test_mjx_experiment_flags_fail_early(tmp_path, flag, message):
    # In this process (tests/script_helpers.py); the test below checks a real process's exit status.
    out = run_in_process("fastsac_go1_mjx.py", flag, f"--logdir={tmp_path / 'x'}")
    assert out.returncode == 2, out.stderr[-2000:]
    assert message in out.stderr and "Traceback" not in out.stderr


def test_mjx_experiment_bad_flag_exits_2_in_a_real_process(tmp_path):
    out = subprocess.run([sys.executable, os.path.join(ROOT, "experiments", "fastsac_go1_mjx.py"), "--num_workers=4",
                          f"--logdir={tmp_path / 'x'}"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "--num_workers is a flag of the CPU-worker runtime" in out.stderr and "Traceback" not in out.stderr

