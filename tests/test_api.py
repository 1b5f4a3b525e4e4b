"""Training from Python (``unilab_jax.train``, ``unilab_jax/apps/api.py``): validated as the command line is, before
anything starts, and returning the run's summary; the end-of-run report of the CLIs."""

import json
import os

import pytest
from script_helpers import run, run_in_process

import unilab_jax
from unilab_jax.config import ConfigError
from unilab_jax.training.trainer import RunConfig

SMALL = {"actor_hidden": (16,), "critic_hidden": (16,), "horizon": 32, "ent_coef": 0.0}


def test_train_returns_the_summary(tmp_path):
    """... and, with ``profile_dir``, writes an in-run trace of the chosen updates that holds the loop's frames."""
    import glob
    import gzip

    logdir, trace = str(tmp_path / "ppo"), str(tmp_path / "trace")
    summary = unilab_jax.train(algo="ppo", task="cartpole_balance", total_steps=20000, logdir=logdir, config=SMALL,
                               task_config={"episode_length": 100}, num_workers=1, envs_per_worker=16, eval_envs=2,
                               profile_dir=trace, profile_start=2, profile_updates=2)
    assert summary["env_steps"] >= 20000 and summary["updates"] > 0 and not summary["interrupted"]
    assert "eval/return" in summary and "warning" not in summary
    assert summary == json.load(open(os.path.join(logdir, "summary.json")))
    (perfetto,) = glob.glob(os.path.join(trace, "**", "perfetto_trace.json.gz"), recursive=True)
    names = {e.get("name", "") for e in json.load(gzip.open(perfetto))["traceEvents"]}
    assert any(n.startswith("$trainer.py") and n.endswith(" _dispatch") for n in names)


@pytest.mark.parametrize("kwargs,error,message", [
    ({"algo": "nope"}, ValueError, "unknown algorithm 'nope'"),
    ({"task": "nope"}, ValueError, "unknown task 'nope'"),
    ({"config": {"learning_rat": 1e-3}}, ConfigError, "unknown config key"),
    ({"config": {"learning_rate": "fast"}}, ConfigError, "learning_rate"),
    ({"task_config": {"episode_lenght": 10}}, ConfigError, "unknown config key"),
    ({"num_workers": 0}, ValueError, "num_workers must be at least 1"),
    ({"total_steps": 0}, ValueError, "total_steps must be positive"),
    ({"num_wokers": 2}, ValueError, "unknown run option"),
    ({"utd_mode": "fast"}, ValueError, "utd_mode"),
    ({"eval_envs": "4"}, ValueError, "eval_envs"),
    ({"replay_dir": "x"}, ValueError, "does not use a replay buffer"),
])
def test_bad_arguments_raise_before_anything_starts(tmp_path, kwargs, error, message):
    args = {"algo": "ppo", "task": "cartpole_balance", "total_steps": 1000, "logdir": str(tmp_path / "run"), **kwargs}
    with pytest.raises(error, match=message):
        unilab_jax.train(**args)
    assert not os.path.exists(tmp_path / "run")


@pytest.mark.parametrize("kwargs,message", [
    ({"task": "nope"}, "unknown task 'nope'"), ({"num_workers": 0}, "num_workers must be a positive integer"),
    ({"algo": "nope"}, "unknown algorithm"), ({"utd_mode": "fast"}, "utd_mode"), ({"eval_every": -1}, "eval_every"),
    ({"profile_updates": 0}, "profile_updates must be a positive integer"), ({"profile_start": -1}, "profile_start"),
])
def test_run_config_rejects_what_cannot_run(kwargs, message):
    with pytest.raises(ValueError, match=message):
        RunConfig(**{"algo": "ppo", "task": "cartpole_balance", **kwargs})


def test_the_package_import_stays_light():
    import subprocess
    import sys

    code = ("import sys, unilab_jax; "
            "print(sorted(m for m in ('jax', 'unilab_jax.apps.api', 'tasks') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_report_names_the_extra_and_ends_with_the_warning(capsys):
    from unilab_jax.apps.cli import report

    report({"logdir": "/tmp/x", "checkpoints": "/tmp/x/checkpoints", "updates": 0, "warning": "no learner update"})
    out = capsys.readouterr().out.splitlines()
    assert "unilab-jax[tensorboard]" in out[-3] and out[-1] == "warning: no learner update"


def test_help_lists_the_run_flags_and_the_configs():
    ppo = run("ppo_cartpole.py", "--help", timeout=120)  # a real process; the others run in this one
    assert ppo.returncode == 0, ppo.stderr[-2000:]
    out = ppo.stdout
    assert "--total_steps (default: 200_000)" in out and "--num_workers (default: 2)" in out
    assert "learning_rate = 0.001" in out and "optimizer step size" in out  # the algorithm's fields and docs
    assert "horizon = 32 [recipe; default 24]" in out and "control steps per trajectory slot" in out
    assert "task cartpole_balance" in out and "|cart x| beyond this terminates" in out  # the task's
    assert "--replay_dir" not in out and "--utd_mode" not in out  # PPO reads no replay flags
    sac = run_in_process("sac_cartpole.py", "--help")
    assert sac.returncode == 0 and "--replay_dir" in sac.stdout and "actor_learning_rate = 0.001 [recipe" in sac.stdout


@pytest.mark.parametrize("script,expect", [("fastsac_go1_mjx.py", "--num_envs (default: 1024)"),
                                           ("sac_franka_pick.py", "--robots"), ("hora_go1.py", "stage 2: hora_student"),
                                           ("hgdagger_franka_pick.py", "--rounds (default: 5)")])
def test_help_of_every_command_line_family(script, expect):
    out = run_in_process(script, "--help")
    assert out.returncode == 0 and expect in out.stdout and "--total_steps" in out.stdout, out.stderr[-2000:]


def test_a_run_without_updates_says_why(tmp_path):
    """The issue's case (learning starts at 10,000 transitions, the run takes fewer): the CLI ends with a warning
    that names learning_starts; each evaluation prints a line."""
    import subprocess
    import sys

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    script = os.path.join(root, "experiments", "sac_mujoco_gym.py")
    out = subprocess.run([sys.executable, script, "--task=gym:Pendulum-v1", "--total_steps=2000", "--num_workers=1",
                          "--envs_per_worker=4", "--eval_envs=1", f"--logdir={tmp_path}"], cwd=root,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    last = out.stdout.strip().splitlines()[-1]
    assert last.startswith("warning: no learner update") and "learning_starts=10000" in last, out.stdout[-2000:]
    assert "eval at step" in out.stdout and json.load(open(tmp_path / "summary.json"))["updates"] == 0


def test_piped_progress_prints_while_the_step_stands_still(capsys, monkeypatch):
    import time

    from unilab_jax.metrics import ProgressBar

    monkeypatch.setattr(ProgressBar, "PLAIN_EVERY_S", 0.05)
    bar = ProgressBar(1000)
    bar.update(100, 1.5)
    time.sleep(0.3)  # no update: a compile, a warm-up
    bar.close()
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) >= 3 and all(line.startswith("step 100/1,000") for line in lines), lines
    assert "episode return 1.500" in lines[-1]


def test_wandb_sink_offline(tmp_path, monkeypatch):
    """--wandb_project / wandb_project=: the run's rows also go to W&B (offline here: kept under <logdir>/wandb)."""
    monkeypatch.setenv("WANDB_MODE", "offline")  # wandb comes with the dev extra: this test never skips
    monkeypatch.setenv("WANDB_SILENT", "true")
    logdir = tmp_path / "run"
    summary = unilab_jax.train("ppo", "cartpole_balance", total_steps=2048, logdir=str(logdir), config=SMALL,
                               task_config={"episode_length": 50}, num_workers=1, envs_per_worker=16, eval_envs=1,
                               wandb_project="unilab-test")
    assert summary["updates"] > 0
    runs = list((logdir / "wandb").glob("offline-run-*"))
    assert len(runs) == 1 and list(runs[0].glob("*.wandb")), list((logdir / "wandb").iterdir())


def test_wandb_project_needs_wandb(tmp_path, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "wandb" else real(name, *a))
    with pytest.raises(ValueError, match=r"unilab-jax\[wandb\]"):
        unilab_jax.train("ppo", "cartpole_balance", total_steps=1000, logdir=str(tmp_path / "run"),
                         wandb_project="x")
