"""bench/rough_standing_falls.py (issue 33's diagnosis tool): variants parsed as NAME=K=V;K=V with Python literals
(tuples keep their commas), bad ones refused with exit 2, and a small run's JSON counts a robot that cannot stand."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import os
import types

import numpy as np
import pytest

import tasks

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_spec = importlib.util.spec_from_file_location("rough_standing_falls",
                                               os.path.join(ROOT, "bench", "rough_standing_falls.py"))
rsf = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rsf)


def test_variants_parse_literals_and_bad_ones_exit_2(tmp_path, capsys):
    assert rsf.parse_variant("base=") == ("base", {})
    assert rsf.parse_variant("x=dr_motor_strength=(1.0,1.0);dr_com_offset=0.0") == (
        "x", {"dr_motor_strength": (1.0, 1.0), "dr_com_offset": 0.0})
    for bad in ("noequals", "=a=1", "x=a"):
        with pytest.raises(ValueError):
            rsf.parse_variant(bad)
    assert rsf.main(["--variant", "x=a", "--out", str(tmp_path / "o.json")]) == 2
    assert "'a' is not K=V" in capsys.readouterr().err


@dataclasses.dataclass(frozen=True)
class _Config:
    terrain_curriculum: bool = True
    fall_every: int = 3  # env e falls at step t when (t + e) % fall_every == 0


class _FallingTask:
    """Two terrain columns (env e on column e % 2); a scripted fall pattern whose count is known in advance."""

    def __init__(self, config, num_envs, seed):
        self.config, self.num_envs, self.t = config, num_envs, 0
        self.spec = types.SimpleNamespace(action_dim=2)
        self.rough = types.SimpleNamespace(levels=np.full(num_envs, 5), cols=np.arange(num_envs) % 2,
                                           terrain=types.SimpleNamespace(columns=("rough", "stairs_up")))

    levels_at_reset: list = []

    def reset(self):
        _FallingTask.levels_at_reset.append(self.rough.levels.copy())

    def step(self, action):
        assert action.shape == (self.num_envs, 2) and not action.any()
        self.t += 1
        fell = (self.t + np.arange(self.num_envs)) % self.config.fall_every == 0
        return types.SimpleNamespace(terminated=fell)


def test_falls_are_counted_per_terrain_type_on_the_asked_level(tmp_path):
    """4 robots x 6 steps, env e falling when (t + e) % 3 == 0 (t = 1..6): 8 falls, 4 on each column; every robot
    put on --level 2 before the reset."""
    tasks.register("falling_test_task", _FallingTask, _Config)
    out = str(tmp_path / "falls.json")
    assert rsf.main(["--task", "falling_test_task", "--variant", "base=", "--variant", "rare=fall_every=7",
                     "--envs", "4", "--steps", "6", "--level", "2", "--flat", "", "--out", out]) == 0
    rows = {r["variant"]: r for r in json.load(open(out))["rows"]}
    assert rows["base"]["terminations"] == 8 and rows["base"]["per_1000_env_steps"] == pytest.approx(1000 * 8 / 24)
    assert rows["base"]["per_type_per_1000"] == {"rough": pytest.approx(1000 * 4 / 12, abs=1e-3),
                                                 "stairs_up": pytest.approx(1000 * 4 / 12, abs=1e-3)}
    assert rows["rare"]["terminations"] == 3  # (t + e) = 7 for (t, e) = (6, 1), (5, 2), (4, 3)
    assert [lv.tolist() for lv in _FallingTask.levels_at_reset] == [[2, 2, 2, 2]] * 2
