"""bench/rough_policy_eval.py (issue 33's diagnosis tool): the shipped Go1 walker (policies/go1_walk.onnx, trained
on the flat floor) run through the rough task frozen on one level and through the flat task; a missing policy
exits 2."""

from __future__ import annotations

import importlib.util
import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
POLICY = os.path.join(ROOT, "policies", "go1_walk.onnx")
sys.path.insert(0, os.path.join(ROOT, "bench"))  # the tool imports rough_standing_falls beside it
_spec = importlib.util.spec_from_file_location("rough_policy_eval", os.path.join(ROOT, "bench", "rough_policy_eval.py"))
rpe = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rpe)


def test_a_flat_walker_on_level_0_and_on_the_flat_floor(tmp_path):
    out = tmp_path / "o.json"
    assert rpe.main(["--policy", POLICY, "--levels", "0", "--envs", "7", "--seconds", "1", "--out", str(out)]) == 0
    rough, flat = json.loads(out.read_text())["rows"]
    assert (rough["variant"], rough["level"], rough["episodes"]) == ("base", 0, 7)
    assert rough["terrain_level"] == 0.0  # every robot on the asked level, curriculum off
    assert {"tracking_error_stairs_up", "fall_rate_obstacles"} <= set(rough)  # one robot per terrain type
    # the walker tracks its commands on the flat floor (0.21-0.24 m/s error over 280 robots, no fall, 10 s): a
    # policy run on the wrong observation or a zero action would stand still: 0.95 here, the mean command speed
    assert flat["task"] == "go1_joystick_flat" and flat["fall_rate"] == 0.0 and flat["tracking_error"] < 0.35


def test_a_missing_policy_exits_2(tmp_path, capsys):
    assert rpe.main(["--policy", str(tmp_path / "none.onnx"), "--out", str(tmp_path / "o.json")]) == 2
    assert "no such file" in capsys.readouterr().err
