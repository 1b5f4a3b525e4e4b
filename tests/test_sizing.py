"""Machine-sized defaults (unilab_jax/sizing.py, ``--num_workers=auto``): the rule as a function of the
core count, the flags resolved into the run before anything starts, bad values rejected cleanly."""

from __future__ import annotations

import math
import os

import pytest
from script_helpers import run_in_process

from unilab_jax import sizing
from unilab_jax.apps import cli


@pytest.mark.parametrize("cores,on_cpu,workers", [
    (1, False, 1), (1, True, 1), (2, False, 1), (2, True, 1), (4, True, 3), (8, True, 6), (8, False, 7),
    (11, False, 10), (12, False, 9), (16, False, 13), (16, True, 12), (64, False, 61), (64, True, 48),
])
def test_auto_workers_leave_the_learner_its_cores(cores, on_cpu, workers):
    assert sizing.auto_num_workers(cores, on_cpu) == workers


@pytest.mark.parametrize("cores,workers,on_cpu,pin", [
    (16, 13, False, 3), (16, 12, False, 3), (16, 14, False, -1), (16, 15, False, -1), (8, 7, False, 1),
    (8, 8, False, -1), (2, 1, False, 1), (1, 1, False, -1), (16, 12, True, -1), (64, 61, False, 3),
])
def test_auto_pinning_keeps_workers_off_an_accelerator_learners_cores(cores, workers, on_cpu, pin):
    assert sizing.auto_pin_cpus(cores, workers, on_cpu) == pin


@pytest.mark.parametrize("total,workers,envs", [(1024, 16, 64), (1024, 15, 69), (1920, 15, 128), (64, 1, 64),
                                                (64, 3, 22), (5, 8, 1)])
def test_auto_envs_split_the_recipe_over_the_workers(total, workers, envs):
    assert sizing.auto_envs_per_worker(total, workers) == envs
    assert envs * workers >= total and (envs - 1) * workers < total


def test_rule_rejects_impossible_inputs_and_parses_flag_values():
    with pytest.raises(ValueError):
        sizing.auto_num_workers(0, False)
    with pytest.raises(ValueError):
        sizing.auto_envs_per_worker(64, 0)
    assert sizing.parse_count("auto") == "auto" and sizing.parse_count("12") == 12 and sizing.parse_count(3) == 3
    with pytest.raises(ValueError, match="an integer or 'auto'"):
        sizing.parse_count("many")
    assert sizing.available_cores() == len(os.sched_getaffinity(0))
    assert str(sizing.SizedFor("a 16-core H100 host", 16, 64)) == "16 workers x 64 envs on a 16-core H100 host"


def _build(argv, sized_for=None):
    cli.FLAGS(["prog", *argv])
    try:
        run, *_ = cli.build_run("ppo", "cartpole_balance", {"horizon": 8, "num_minibatches": 2}, {}, 1000, sized_for)
        return run
    finally:
        cli.FLAGS.unparse_flags()


def test_auto_flags_reach_the_run_config(tmp_path, capsys):
    cores = sizing.available_cores()
    assert sizing.learner_on_cpu("jax")  # JAX runs on this machine's CPU (no accelerator here)
    workers = sizing.auto_num_workers(cores, learner_on_cpu=True)
    recipe = sizing.SizedFor("a test machine", 4, 16)
    run = _build(["--num_workers=auto", f"--logdir={tmp_path}"], recipe)
    assert (run.num_workers, run.envs_per_worker) == (workers, math.ceil(64 / workers))
    plural = "s" if workers != 1 else ""
    assert (f"sized for this machine: {workers} worker{plural} x {math.ceil(64 / workers)} envs ({cores} cores; "
            "the recipe was sized for 4 workers x 16 envs on a test machine)") in capsys.readouterr().out
    # An explicit envs_per_worker stays; auto envs with explicit workers split the recipe over them.
    run = _build(["--num_workers=auto", "--envs_per_worker=8", f"--logdir={tmp_path}"], recipe)
    assert (run.num_workers, run.envs_per_worker) == (workers, 8)
    run = _build(["--num_workers=3", "--envs_per_worker=auto", f"--logdir={tmp_path}"], recipe)
    assert (run.num_workers, run.envs_per_worker) == (3, 22)
    capsys.readouterr()
    # Without auto nothing changes and nothing is printed (the defaults: 2 x 32).
    run = _build([f"--logdir={tmp_path}"])
    assert (run.num_workers, run.envs_per_worker) == (2, 32) and "sized for" not in capsys.readouterr().out
    # --pin_cpus=auto (the default) confines no worker when the learner computes on the CPU; a number stays.
    assert run.pin_cpus == -1 and "kept off" not in capsys.readouterr().out
    assert _build(["--pin_cpus=1", f"--logdir={tmp_path}"]).pin_cpus == 1


@pytest.mark.parametrize("flag,code,message", [
    ("--num_workers=many", 1, "an integer or 'auto'"),
    ("--envs_per_worker=1.5", 1, "an integer or 'auto'"),
    ("--envs_per_worker=0", 2, "--envs_per_worker must be at least 1"),
])
def test_bad_sizing_flags_fail_before_workers_start(tmp_path, flag, code, message):
    # In this process (tests/script_helpers.py): absl's parse error exits 1, the run's own checks 2.
    out = run_in_process("ppo_cartpole.py", flag, f"--logdir={tmp_path / 'x'}")
    assert out.returncode == code, out.stderr[-2000:]
    assert message in out.stderr and "Traceback" not in out.stderr
