"""RLPD and SAC on peg insertion through robot servers: the experiment command, its flag checks."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from script_helpers import run_in_process

from unilab_jax.apps.play import main as play_main
from unilab_jax.runtime.replay_store import ReplayStore

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# test_rlpd_improves_on_its_first_evaluation: the last checkpoint's return over the first's, on the same 8 episodes.
# The first checkpoint's return hardly varies (-0.024 .. -0.001: an untrained policy barely moves the peg). With the
# robots at speed 50 (sessions before 2026-11-28) the gains ranged from -0.003 to 0.45 over seeds and reruns, moving
# with the machine's load (most steps late); unpaced (the test's --speed=inf), 2026-11-28, two runs at a time: seed 0
# 0.34 / 0.36 / 0.39, seeds 1-5 0.32 / 0.37 / 0.09 / 0.30 / 0.26 at 900 env steps; at 600, seed 0 0.15 / 0.13 / 0.05
# and seeds 1-5 0.08-0.19. With the target evaluating only its 2 subset members (the same day, 900 env steps): seeds
# 0-5 0.35 / 0.12 / 0.40 / 0.38 / 0.30 / 0.27, and 0.30 in this test's own run. The threshold holds a margin of 0.04
# below the lowest seed's run at 900 (seed 3, before) and of 0.25 below seed 0's runs. An ensemble of 5 critics was
# tried before (a fresh-clone CI run gained 0.025 on seed 0 at speed 50): the test keeps the recipe's 10.
THRESHOLD = 0.05


def _script(name: str, *args: str, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, os.path.join(ROOT, "experiments", name), *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def test_rlpd_franka_peg_records_demos_and_trains(tmp_path):
    """The plain command: images (the front and wrist cameras' frames rendered by the sim: server) + proprioception, 20
    demonstrations recorded with images, RLPD with the image encoder. 400 env steps (learning starts at 300:
    ~50 gradient steps at the image recipe's utd 0.5, ~20 learner calls, each logging the prior rows and the
    ensemble's spread) exercise what 2000 did, and 2 gradient steps per call, not the recipe's 16: on the CPU
    the image learner unrolls its steps, so the first call's compile grows with them (16: 47 s, 4: 14 s on the
    2-core VM; later, the first call 7.3 s at 4 and 5.1 s at 2). The script at 500 steps and 4 per call: 26.2-27.7
    CPU-s, at 400 and 2: 19.1-20.3 (three runs each, alternating). The cameras draw the arm's collision geometry
    (``camera_geometry=collision``): its visual meshes cost ~15 ms a frame in software GL, ~25 CPU-s over the ~1900
    frames of a 500-step run, and are rendered in tests/robots/test_image_obs.py."""
    logdir = tmp_path / "run"
    out = _script("rlpd_franka_peg.py", "--speed=20", "--total_steps=400", "--config", "updates_per_call=2",
                  "--task_config=camera_geometry=collision", f"--logdir={logdir}", timeout=500)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "demonstrations: 20 episodes (" in out.stdout
    assert "image observation 32x32x12 uint8 (front,wrist x 2 frames)" in out.stdout
    with ReplayStore(str(logdir / "demos")) as store:
        rows = store.read(store.first_row, store.committed)
    assert rows["image"].shape[1:] == rows["next_image"].shape[1:] == (32, 32, 12)
    # no privileged state in the critic's observation either (critic_state off): proprio 13 + kind 2 + time 1
    assert rows["obs"].shape[1:] == (15,) and rows["critic_obs"].shape[1:] == (16,)
    assert rows["image"].dtype == np.uint8 and rows["image"].std() > 5  # rendered scenes
    assert len(set(rows["episode"].tolist())) == 20
    for e in range(20):  # the label: the episode ended by success (termination), not by its time limit
        ep = rows["episode"] == e
        assert rows["success"][ep].all() == rows["terminated"][ep][-1]
    # the expert succeeds in nearly all (a robot paced at speed 20 on a loaded VM may miss one: 19/20 seen once)
    assert rows["success"][np.r_[np.flatnonzero(np.diff(rows["episode"])), len(rows["episode"]) - 1]].sum() >= 17
    metrics = [json.loads(line) for line in open(logdir / "metrics.jsonl")]
    prior_rows = [r["perf/prior_rows"] for r in metrics if "perf/prior_rows" in r]
    assert prior_rows and set(prior_rows) == {64.0}  # half of each batch of 128 from the demonstrations
    assert any("loss/q_std" in r for r in metrics)  # the ensemble's spread: RLPD's critic ran
    summary = json.load(open(logdir / "summary.json"))
    assert summary["env_steps"] >= 400 and not summary["interrupted"]
    assert 0.0 <= summary["eval/success_rate"] <= 1.0 and np.isfinite(summary["eval/return"])
    # robot time at speed 1: 400 steps at 10 Hz plus the demonstrations' own steps
    assert summary["robot_s"] == pytest.approx(40.0 + len(rows["reward"]) / 10.0, abs=0.2)
    assert not (logdir / "demos.partial").exists()
    # these demonstrations hold no robot-identity one-hot (the robot experiments leave it out): a run that asks
    # for the one-hot on two robots refuses them before it trains
    out = _script("rlpd_franka_peg.py", "--robots=sim:franka_emika_panda,sim:franka_emika_panda",
                  "--task_config=robot_identity=true", f"--demos={logdir / 'demos'}",
                  f"--logdir={tmp_path / 'other'}", timeout=200)
    assert out.returncode == 2 and "this run needs" in out.stderr and "Traceback" not in out.stderr, out.stderr[-2000:]


@pytest.mark.parametrize("script,args,message", [
    ("sac_franka_peg.py", ["--demos=/nonexistent"], "learns without prior data"),
    ("rlpd_franka_peg.py", ["--demos=/nonexistent"], "no replay store there"),
    ("rlpd_franka_peg.py", ["--task=cartpole_balance"], "this experiment drives robots"),
    ("rlpd_franka_peg.py", ["--eval_every=100"], "evaluation needs 1 more"),
    ("rlpd_franka_peg.py", ["--config", "prior_fraction=1.0"], "prior_fraction must be in [0, 1)"),
    ("rlpd_franka_peg.py", ["--task_config=image_size=16", "--config", "encoder_channels=(8, 8, 8, 8)", "--config",
                            "encoder_strides=(2, 2, 2, 2)"], "is too small for 4 3x3 convolutions"),
    # a critic with the privileged state beside an image-only actor only as the stated asymmetric actor-critic
    ("rlpd_franka_peg.py", ["--task_config=critic_state=true"], "use --asymmetric"),
    ("rlpd_franka_peg.py", ["--asymmetric", "--observation=state"], "--asymmetric: with --observation=images only"),
    # --algo: the experiment's learner and data with another actor only; the flow actor's run builds its own config
    ("rlpd_franka_peg.py", ["--algo=sac"], "--algo='sac': this experiment runs rlpd or rlpd_flow"),
    ("sac_franka_peg.py", ["--algo=nope"], "--algo='nope': this experiment runs sac or sacflow"),
    ("rlpd_franka_peg.py", ["--algo=rlpd_flow", "--config", "flow_steps=0"], "RLPDFlowConfig: flow_steps must be in"),
])
def test_bad_flags_exit_2_before_anything_starts(tmp_path, script, args, message):
    # In this process (tests/script_helpers.py); the last check of the test above is a real process's exit 2.
    out = run_in_process(script, *args, f"--logdir={tmp_path / 'x'}")
    assert out.returncode == 2, out.stderr[-2000:]
    assert message in out.stderr and "Traceback" not in out.stderr


def test_rlpd_improves_on_its_first_evaluation(tmp_path, capsys):
    """The cheapest learning configuration: state-based peg insertion (``--observation=state``) with the dense
    reward and the rotation locked, three robots unpaced (``--speed=inf``; one trains, two evaluate every 300 steps
    while it does), 900 env steps, utd 8.

    The dense reward is potential-based (10 x success + potential(s') - potential(s)): an episode without success
    returns the potential's change, in [-1, 1]. The run's own 2-episode evaluations are too few to rank, so the first
    and the last checkpoints are compared on the same 8 episodes (``python -m unilab_jax.play``, in-process robots,
    one seed). Unpaced robots, because at speed 50 the outcome moved with the machine's load: 70-83% of the steps
    were late (the robot held its command while ``utd_mode=hold`` paused the worker for the learner), and seed 0
    gained 0.36, 0.28, 0.25, 0.11, -0.003 in five runs on the loaded 2-core VM. Unpaced, no step is late; gains
    measured there (2026-11-28, two runs at a time as the suite's workers): seed 0 0.34, 0.36, 0.39; seeds 1-5 0.32,
    0.37, 0.09, 0.30, 0.26. At 600 env steps seed 0 gained 0.15, 0.13, 0.05: too close to THRESHOLD (0.05), so the
    budget stays 900. The run samples through the device mirror (``--replay_on_device=on``, as on a GPU) to cover
    prior data composed with it.
    """
    logdir = tmp_path / "run"
    robots = ",".join(["sim:franka_emika_panda"] * 3)
    out = _script("rlpd_franka_peg.py", "--observation=state", f"--robots={robots}", "--num_workers=1", "--eval_envs=2",
                  "--eval_every=300",
                  "--speed=inf", "--total_steps=900", "--dense_reward", "--config", "utd=8", "--config",
                  "init_alpha=0.05", "--task_config=lock_rotation=true", "--replay_on_device=on", f"--logdir={logdir}",
                  timeout=400)
    assert out.returncode == 0, out.stderr[-3000:]
    evals = [json.loads(line) for line in open(logdir / "metrics.jsonl")]
    evals = [(r["step"], r["eval/return"]) for r in evals if "eval/return" in r]
    assert len(evals) >= 3 and evals[0][0] <= 400, evals
    # The run's robot servers are gone with it: playing its policy needs other robots, e.g. in-process ones.
    # (``python -m unilab_jax.play``'s main in this process: three interpreters' imports saved)
    play = [f"--logdir={logdir}"]
    capsys.readouterr()
    # Each silent address costs one call's timeout (timeout_s, 2 s by default: 6 s of waiting for the three); at
    # 0.4 s the first round over the three (1.2 s) already passes the 1 s connect timeout.
    assert play_main([*play, "--episodes=2", "--task_config=connect_timeout_s=1", "--task_config=timeout_s=0.4"]) == 2
    assert "robots wanted, 0 free" in capsys.readouterr().err
    steps = sorted(int(n) for n in os.listdir(logdir / "checkpoints") if n.isdigit())
    assert steps[0] <= 400 and steps[-1] >= 900, steps
    returns = []
    for step in (steps[0], steps[-1]):
        code = play_main([*play, f"--checkpoint={step}", "--episodes=8", "--seed=1", "--task_config=robots=()",
                          "--task_config=dense_reward=true"])
        local = capsys.readouterr()
        assert code == 0, local.err[-2000:]
        stats = json.loads(local.out)
        assert stats["episodes"] == 8 and 0.0 <= stats["success_rate"] <= 1.0 and np.isfinite(stats["return"])
        returns.append(stats["return"])
    print("in-run evaluations:", evals, "first and last checkpoint on 8 episodes:", returns)
    assert returns[1] > returns[0] + THRESHOLD, returns
