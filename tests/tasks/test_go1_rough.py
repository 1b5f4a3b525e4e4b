"""``go1_joystick_rough`` on the real simulation: robots start on the terrain, stay on it, the curriculum moves
levels at reset, the height scan reaches the critic, the metrics and the evaluation on hard cells."""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np
import pytest

import tasks
from tasks import curriculum, go1_math, rough, terrain
from unilab_jax.metrics import WALKING

CLEAN = {"noise_level": 0.0, "domain_randomization": False}


def _deepest_contact(task) -> float:
    """The deepest penetration (most negative contact distance; 0 without contacts) of any foot into the terrain
    over the task's envs: the feet are the only geoms that collide, and only with the terrain."""
    deepest = 0.0
    for i in range(task.num_envs):
        _, data = task.render_scene(i)
        if data.ncon:
            deepest = min(deepest, float(data.contact.dist[: data.ncon].min()))
    return deepest


def test_robots_start_on_the_surface_and_stay_on_it_under_random_actions():
    # every type at the top level, spawned up to 3 m from the cell centre (onto slopes, stair edges, obstacles)
    task = tasks.make("go1_joystick_rough", 14, seed=0, overrides={**CLEAN, "reset_xy": 3.0, "max_init_level": 9})
    task.rough.levels[:] = 9
    task.reset()
    # Playground's home pose stands the feet 1.65 cm into a flat floor (soft contacts): on the terrain no foot
    # starts deeper, and the lowest foot starts at most a step (0.14 m, + 1 cm of sampling) above the ground
    assert _deepest_contact(task) > -0.0165 - 1e-4
    for i in range(14):
        model, data = task.render_scene(i)
        feet = np.array([data.geom_xpos[model.geom(f).id] for f in go1_math.FEET])
        gap = feet[:, 2] - model.geom_size[model.geom("FR").id, 0] - terrain.ground_height(
            task.rough.sampler, feet[:, 0], feet[:, 1])
        assert gap.min() < 0.15
    ground = terrain.ground_height(task.rough.sampler, task.sim.qpos[:, 0], task.sim.qpos[:, 1])
    assert (task.sim.qpos[:, 2] - ground > 0.278 - 0.02).all()
    rng = np.random.default_rng(0)
    deepest = 0.0
    for _ in range(300):
        out = task.step(rng.uniform(-1, 1, (14, 12)).astype(np.float32))
        assert np.isfinite(out.obs).all() and np.isfinite(out.critic_obs).all()
        deepest = min(deepest, _deepest_contact(task))
    assert deepest > -0.05, "a foot sank into the terrain"
    assert task.unstable_count == 0
    task.close()


def test_curriculum_moves_levels_at_reset_when_distances_are_forced():
    over = {**CLEAN, "reset_xy": 0.0, "episode_length": 5, "command_resample_mean_s": 1e6}
    task = tasks.make("go1_joystick_rough", 4, seed=1, overrides=over)
    task.rough.levels[:] = [3, 3, 9, 3]
    task.reset()
    origins = task.rough.origins(np.arange(4))
    np.testing.assert_allclose(task.sim.qpos[:, :2], origins[:, :2])
    # env 0 walked 4.5 m (> half of an 8 m cell), env 2 too but from the top level; env 1 stays while its
    # command asks for 1.5 m/s over the 0.1 s episode (0.15 m, of which it walks < half); env 3 asks for nothing
    qpos, qvel = task.sim.qpos.copy(), task.sim.qvel.copy()
    qpos[[0, 2], 0] += 4.5
    task.sim.set_state(np.arange(4), qpos, qvel, ctrl=np.tile(task.default_pose, (4, 1)))
    task.command[:] = [[0.0, 0.0, 0.0], [1.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    zero = np.zeros((4, 12), np.float32)
    for _ in range(4):
        assert not (task.step(zero).truncated.any())
    out = task.step(zero)
    assert out.truncated.all()
    np.testing.assert_array_equal(out.extras["terrain_level"], [3, 3, 9, 3])  # the ended episodes' levels
    np.testing.assert_array_equal(out.extras["terrain_level_3"], [1, 1, 0, 1])
    assert task.rough.levels[0] == 4 and task.rough.levels[1] == 2 and task.rough.levels[3] == 3
    assert 0 <= task.rough.levels[2] < 10
    # the new episodes start at the new cells' origins
    np.testing.assert_allclose(task.sim.qpos[:, :2], task.rough.origins(np.arange(4))[:, :2])
    task.close()


def test_height_scan_is_in_the_critic_observation_and_the_perceptive_actor():
    task = tasks.make("go1_joystick_rough", 7, seed=0, overrides={**CLEAN, "reset_xy": 0.0})
    assert task.spec.obs_dim == 48 and task.spec.critic_obs_dim == 123 + 187
    obs, cobs = task.reset()
    np.testing.assert_allclose(cobs[:, 123:], task.rough.scan(task.sim.qpos), atol=1e-6)
    # stairs_down's platform is flat: the scan's centre reads the base's height above it, negated
    stairs = list(task.rough.terrain.columns).index("stairs_down")
    env = int(np.flatnonzero(task.rough.cols == stairs)[0])
    platform = task.rough.origins(np.array([env]))[0, 2]
    assert cobs[env, 123 + 93] == pytest.approx(platform - task.sim.qpos[env, 2], abs=1e-5)  # point 93: (0, 0)
    task.close()
    seeing = tasks.make("go1_joystick_rough", 2, seed=0, overrides={**CLEAN, "perceptive": True})
    obs, cobs = seeing.reset()
    assert obs.shape == (2, 48 + 187)
    np.testing.assert_array_equal(obs[:, 48:], cobs[:, 123:])
    seeing.close()


def test_evaluation_runs_on_hard_cells_and_reports_each_terrain_type():
    task = tasks.make("go1_joystick_rough", 14, seed=0, overrides={**CLEAN, "episode_length": 20})
    tracker = task.eval_tracker()
    levels = task.rough.levels.copy()
    np.testing.assert_array_equal(levels, [5] * 7 + [6] * 7)  # the upper half of 10 levels, every column
    np.testing.assert_array_equal(task.rough.cols, list(range(7)) * 2)
    task.reset()
    for _ in range(25):
        tracker.step(np.zeros((14, 12), np.float32))
    np.testing.assert_array_equal(task.rough.levels, levels)  # episodes ended: the curriculum stays frozen
    result = tracker.result()
    assert set(tracker.LOGGED) <= set(result) and len(set(tracker.LOGGED)) == len(tracker.LOGGED)  # no name twice
    for t in terrain.TYPES:
        assert result[f"walking_{t}"] in (0.0, 1.0) and np.isfinite(result[f"tracking_error_{t}"])
    # standing still does not walk: the per-type criterion fails where commands ask for motion
    assert not WALKING.met(result)
    levels = (result["terrain_level_min"], result["terrain_level_top"])
    assert levels == (5.0, 9.0) and result["rough_terrain_walking"] == 0.0
    # the rough-terrain criterion: the walking numbers on an evaluation of levels >= half the top level
    walks = {**result, "tracking_error": 0.1, "yaw_rate_error": 0.1, "fall_rate": 0.0}
    assert WALKING.met_on_rough(walks) and not WALKING.met_on_rough({**walks, "terrain_level_min": 4.0})
    task.close()


def test_history_variant_keeps_the_terrain_metrics():
    task = tasks.make("go1_joystick_rough_hist", 2, seed=0, overrides={**CLEAN, "episode_length": 2})
    assert task.spec.episode_metrics[0] == "terrain_level"
    task.reset()
    task.step(np.zeros((2, 12), np.float32))
    out = task.step(np.zeros((2, 12), np.float32))
    assert out.truncated.all() and set(out.extras) == set(task.spec.episode_metrics)
    task.close()


def test_command_curriculum_widens_after_well_tracked_episodes_and_off_map_truncates():
    config = rough.RoughConfig(terrain_levels=2, terrain_columns=("rough",), terrain_cell_size=2.0, terrain_border=2.0,
                               terrain_platform=1.0, max_init_level=1, command_curriculum=True)
    state = rough.TerrainState(config, num_envs=2, seed=0, ctrl_dt=0.02, episode_length=10)
    np.testing.assert_allclose(state.command_fraction, [0.5, 0.5, 0.5])
    cmd = np.zeros((2, 3))
    for _ in range(10):  # a full episode tracked at 0.9 of the maximum
        state.record_step(cmd, np.full(2, 0.9), np.zeros((2, 2)), np.zeros(2))
    qpos = np.zeros((2, 7))
    qpos[:, :2] = state.origins(np.arange(2))[:, :2]
    state.episode_end(np.array([0]), qpos[:1], np.array([10]), np.array([False]))
    np.testing.assert_allclose(state.command_fraction, 0.5)  # one episode of two envs: not yet an update
    state.episode_end(np.array([1]), qpos[1:], np.array([10]), np.array([False]))
    np.testing.assert_allclose(state.command_fraction, 0.6)  # mean 0.9 >= 0.8: + 0.1 per axis
    for _ in range(5):  # half an episode at 0.9 (then it fell): 0.45 per step of a full episode
        state.record_step(cmd, np.full(2, 0.9), np.zeros((2, 2)), np.zeros(2))
    state.episode_end(np.arange(2), qpos, np.array([5, 5]), np.zeros(2, bool))
    np.testing.assert_allclose(state.command_fraction, 0.6)
    # the map is 4 m x 2 m of cells within a 2 m border: robots within 1 m of its edge are off it
    np.testing.assert_array_equal(state.off_map(np.array([[-0.9, 1, 0], [-1.1, 1, 0], [4.9, 1, 0], [1, 3.1, 0.0]])),
                                  [False, True, False, True])


def test_path_curriculum_promotes_a_robot_that_rides_its_circle():
    """One yaw-rate command a whole episode: 0.5 m/s at 2 pi / 20 rad/s is a full circle in 20 s. A robot that rides
    it ends where it started: the displacement rule keeps it (0 m from the origin, 0 asked), the path rule promotes
    it (10 m made along its command > 4 m). One that stood still and one that backed away against its command
    (-5 m) are demoted by the path rule (< 10 m / 2); the displacement rule keeps both (a full circle asks for 0 m)."""
    steps, dt = 1000, 0.02
    for mode, expected in (("displacement", [3, 3, 3]), ("path", [4, 2, 2])):
        config = rough.RoughConfig(terrain_columns=("rough",), max_init_level=3, curriculum_distance=mode)
        state = rough.TerrainState(config, num_envs=3, seed=0, ctrl_dt=dt, episode_length=steps)
        state.levels[:] = 3
        cmd = np.tile([0.5, 0.0, 2 * np.pi / 20], (3, 1))
        yaw = np.zeros(3)
        for _ in range(steps):
            heading = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
            velocity = heading * np.array([[0.5], [0.0], [-0.25]])  # env 0 rides the circle, 2 backs along it
            state.record_step(cmd, np.ones(3), velocity, yaw)
            yaw = yaw + np.array([2 * np.pi / 20, 0.0, 2 * np.pi / 20]) * dt
        qpos = np.zeros((3, 7))
        # env 0 back near its start, env 1 never left (sway), env 2 on its small circle: 0.05-0.1 m from the start
        qpos[:, :2] = state.origins(np.arange(3))[:, :2] + [[0.05, 0.0], [0.0, 0.05], [0.0, 0.1]]
        state.episode_end(np.arange(3), qpos, np.full(3, steps), np.zeros(3, bool))
        np.testing.assert_array_equal(state.levels, expected, err_msg=mode)
        np.testing.assert_array_equal(state.walked, 0.0)  # the next episode starts its sums again
    np.testing.assert_allclose(curriculum.advance_walked_path(
        np.zeros(2), np.zeros(2), np.array([[0.0, 1.0], [3.0, 4.0]]), np.array([np.pi / 2, 0.0]),
        np.array([[2.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), 0.5), [[0.5, 0.0], [1.0, 0.0]], atol=1e-12)
    with pytest.raises(ValueError, match="curriculum_distance"):
        rough.TerrainState(rough.RoughConfig(curriculum_distance="reach"), 1, 0, 0.02, 10)


def _walker(policy_file: str):
    """``obs -> action`` of a shipped flat-ground walker (``policies/<policy_file>``, ONNX) through onnxruntime."""
    ort = pytest.importorskip("onnxruntime")
    policy = ort.InferenceSession(os.path.join(os.path.dirname(__file__), "..", "..", "policies", policy_file),
                                  providers=["CPUExecutionProvider"])
    name = policy.get_inputs()[0].name
    return lambda obs: policy.run(None, {name: obs.astype(np.float32)})[0]


def _tilted_contact_fraction(overrides: dict) -> float:
    """The share of foot contacts whose normal is tilted (z < 0.99) while the shipped flat-ground walker walks 100
    control steps on a heightfield with every height zero: a plane would give none."""
    walker = _walker("go1_walk.onnx")
    task = tasks.make("go1_joystick_rough", 4, seed=0, overrides={
        **CLEAN, "terrain_curriculum": False, "terrain_rough_height": (0.0, 0.0), "terrain_columns": ("rough",),
        **overrides})
    try:
        task.rough.levels[:] = 0
        obs, _ = task.reset()
        normals = []
        for _ in range(100):
            obs = task.step(walker(obs)).obs
            for i in range(task.num_envs):
                _, data = task.render_scene(i)
                normals.extend(data.contact.frame[: data.ncon, 2])
    finally:
        task.close()
    return float((np.asarray(normals) < 0.99).mean())


def test_the_stiffer_terrain_contact_keeps_feet_off_the_heightfields_side_faces():
    # A foot sunk deeper than its sphere's radius (Go1: 2.3 cm) touches the side faces of the heightfield's prisms
    # (horizontal normals on flat ground). With the plane's solref (0.02, 1) 40% of the walker's contacts were tilted
    # (seeds 0 and 1: 0.399, 0.408), with the default (0.01, 1) 18% (0.181, 0.183); the flat walker fell in 26% of
    # 10 s episodes on level 0 as trained, and in 1.4% with the stiffer contact (bench/rough_policy_eval.py)
    task = tasks.make("go1_joystick_rough", 1, seed=0, overrides=CLEAN)
    assert tuple(task.model.geom("floor").solref) == (0.01, 1.0)
    task.close()
    assert _tilted_contact_fraction({}) < 0.3 < _tilted_contact_fraction({"terrain_solref": (0.02, 1.0)})
    with pytest.raises(ValueError, match="terrain_solref"):
        tasks.make("go1_joystick_rough", 1, seed=0, overrides={**CLEAN, "terrain_solref": (0.01,)})


def test_a_resumed_run_starts_its_robots_at_the_level_distribution_it_stopped_at(tmp_path):
    """``resumed_level_weights``: the mean level histogram of the training rows of the last episode's duration
    (hand-computed below);
    ``init_level_weights`` then draws the initial levels from it; bad weights are refused."""
    rows = [{"step": 1, "time/wall_s": 10.0, **{f"episode/terrain_level_{k}": float(k == 0) for k in range(3)}},
            {"step": 2, "time/wall_s": 50.0, "episode/terrain_level_0": 0.0, "episode/terrain_level_1": 0.5,
             "episode/terrain_level_2": 0.5},
            {"step": 2, "eval/return": 1.0},
            {"step": 3, "time/wall_s": 65.0, "episode/terrain_level_0": 0.0, "episode/terrain_level_1": 0.0,
             "episode/terrain_level_2": 1.0}]
    path = tmp_path / "metrics.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert rough.resumed_level_weights(str(path), 3, 20.0) == (0.0, 0.25, 0.75)  # rows at 50 and 65 s, not at 10
    assert rough.resumed_level_weights(str(path), 3, 60.0) == (0.3333, 0.1667, 0.5)  # a longer episode: all three
    assert rough.resumed_level_weights(str(path), 4, 20.0) == ()  # another grid
    assert rough.resumed_level_weights(str(tmp_path / "none.jsonl"), 3, 20.0) == ()
    config = rough.RoughConfig(terrain_levels=3, terrain_columns=("rough",), terrain_cell_size=2.0,
                               terrain_border=2.0, terrain_platform=1.0, max_init_level=0,
                               init_level_weights=(0.0, 0.25, 0.75))
    state = rough.TerrainState(config, num_envs=400, seed=0, ctrl_dt=0.02, episode_length=10)
    counts = np.bincount(state.levels, minlength=3)
    assert counts[0] == 0 and 70 <= counts[1] <= 130 and counts[1] + counts[2] == 400  # binomial sd ~8.7
    for bad in ((1.0, 1.0), (0.0, 0.0, 0.0), (1.0, -0.5, 1.0)):
        with pytest.raises(ValueError, match="init_level_weights"):
            rough.TerrainState(dataclasses.replace(config, init_level_weights=bad), num_envs=2, seed=0,
                               ctrl_dt=0.02, episode_length=10)


def test_resume_sets_the_initial_levels_from_the_run_s_metrics_unless_given(tmp_path):
    from unilab_jax.apps import api

    (tmp_path / "checkpoints").mkdir()
    levels = {f"episode/terrain_level_{k}": float(k == 7) for k in range(10)}
    (tmp_path / "metrics.jsonl").write_text(json.dumps({"step": 5, "time/wall_s": 30.0, **levels}) + "\n")
    *_, overrides = api.build("fastsac", "go1_joystick_rough", logdir=str(tmp_path), total_steps=1000, resume=True)
    assert overrides["init_level_weights"] == tuple(float(k == 7) for k in range(10))
    given = (1.0,) + (0.0,) * 9
    *_, overrides = api.build("fastsac", "go1_joystick_rough", logdir=str(tmp_path), total_steps=1000, resume=True,
                              task_config={"init_level_weights": given})
    assert overrides["init_level_weights"] == given  # the user's choice stands
    *_, overrides = api.build("fastsac", "go1_joystick_rough", logdir=str(tmp_path), total_steps=1000)
    assert "init_level_weights" not in overrides  # a new run starts at the initial levels
