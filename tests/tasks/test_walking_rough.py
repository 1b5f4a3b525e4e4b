"""``go2_joystick_rough`` and ``g1_walk_rough`` on the real simulation: robots start on the terrain and stay on it,
heights are read above the ground, the scan reaches the critic, the evaluation runs on hard cells."""

from __future__ import annotations

import numpy as np
import pytest
from test_go1_rough import CLEAN, _deepest_contact, _walker

import tasks
from tasks import terrain


@pytest.mark.parametrize("name", ["go2_joystick_rough", "g1_walk_rough"])
def test_walkers_start_on_the_surface_and_stay_on_it(name):
    # every type at the top level, spawned up to 3 m from the cell centre (onto slopes, stair edges, obstacles)
    task = tasks.make(name, 7, seed=0, overrides={**CLEAN, "reset_xy": 3.0, "max_init_level": 9})
    task.rough.levels[:] = 9
    _, cobs = task.reset()
    assert _deepest_contact(task) > -0.02
    assert (task.sim.qpos[:, 2] - task.base_ground() > task.init_qpos[2] - 0.02).all()
    assert task.sim.qpos[:, 2].max() > 1.0  # some robots stand high on the grid: heights must be relative
    np.testing.assert_allclose(cobs[:, -187:], task.rough.scan(task.sim.qpos), atol=1e-6)
    rng = np.random.default_rng(0)
    deepest = 0.0
    for _ in range(60):
        out = task.step(rng.uniform(-1, 1, (7, task.spec.action_dim)).astype(np.float32))
        assert np.isfinite(out.critic_obs).all()
        deepest = min(deepest, _deepest_contact(task))
    assert deepest > -0.05, "a foot sank into the terrain"
    assert task.unstable_count == 0
    task.close()


def test_heights_are_above_the_ground():
    g1 = tasks.make("g1_walk_rough", 7, seed=0, overrides={**CLEAN, "reset_xy": 0.0})
    assert g1.spec.obs_dim == 58 and g1.spec.critic_obs_dim == 66 + 187
    _, cobs = g1.reset()
    # G1's critic reads the pelvis height and both feet's heights (58 + 3: base_z, contacts, feet_h)
    ground = terrain.ground_height(g1.rough.sampler, g1.sim.qpos[:, 0], g1.sim.qpos[:, 1])
    np.testing.assert_allclose(cobs[:, 61], g1.sim.qpos[:, 2] - ground, atol=1e-5)
    # standing feet on the flat platforms in the middle of the slope, stairs and obstacle cells: soles on the
    # ground (5 mm spheres 0.5 mm into it), whatever the platform's height
    flat = np.isin(np.asarray(g1.rough.terrain.columns)[g1.rough.cols], ["slope_up", "slope_down", "stairs_up",
                                                                         "stairs_down", "obstacles"])
    np.testing.assert_allclose(cobs[flat, 64:66], 0.0, atol=1e-3)
    assert np.abs(ground[flat]).max() > 0.1
    g1.close()
    go2 = tasks.make("go2_joystick_rough", 7, seed=0, overrides={**CLEAN, "reset_xy": 0.0, "max_init_level": 9})
    go2.rough.levels[:] = 9
    go2.reset()
    out = go2.step(np.zeros((7, 12), np.float32))
    # (base height above the ground - 0.3)^2 x 20 x 0.02: small for a standing robot, ~0.3 if it read 1 m of cell
    assert np.abs(out.reward_terms["base_height"]).max() < 2e-3
    assert go2.sim.qpos[:, 2].max() > 1.0
    # a Go2 thrown 4 m above the ground (nothing else ends its episode: a GPU run's base-height penalty of a robot
    # flying on for the episode reached 1e7-1e8) is truncated at once, its reward that of one step; one under the
    # ground terminates (min_base_height 0 above the ground under it)
    qpos, qvel = go2.sim.qpos.copy(), go2.sim.qvel.copy()
    qpos[0, 2] = go2.base_ground()[0] + 4.0
    qpos[1, 2] = go2.base_ground()[1] - 1.0
    go2.sim.set_state(np.arange(7), qpos, qvel)
    out = go2.step(np.zeros((7, 12), np.float32))
    assert out.truncated[0] and not out.terminated[0] and out.terminated[1] and not out.truncated[1:].any()
    assert -10.0 < out.reward[0] < 0.0
    go2.close()


def test_walking_evaluation_reports_each_terrain_type():
    task = tasks.make("go2_joystick_rough", 7, seed=0, overrides={**CLEAN, "episode_length": 10})
    tracker = task.eval_tracker()
    np.testing.assert_array_equal(task.rough.levels, [5] * 7)
    np.testing.assert_allclose(task._cmd_high, task.config.command_high)
    task.reset()
    for _ in range(12):
        out = tracker.step(np.zeros((7, 12), np.float32))
    assert set(out.extras) == set(task.spec.episode_metrics)
    result = tracker.result()
    for t in terrain.TYPES:
        assert result[f"walking_{t}"] in (0.0, 1.0)
    task.close()


def _g1_walker_falls(overrides: dict, envs: int = 4, steps: int = 150) -> int:
    """How many of ``envs`` G1s driven by the shipped flat-ground walker fall within ``steps`` control steps (3 s) on
    a heightfield with every height zero, no randomisation."""
    walker = _walker("g1_walk.onnx")
    task = tasks.make("g1_walk_rough", envs, seed=0, overrides={
        "noise_level": 0.0, "domain_randomization": False, "terrain_curriculum": False,
        "terrain_rough_height": (0.0, 0.0), "terrain_columns": ("rough",), **overrides})
    try:
        task.rough.levels[:] = 0
        obs, _ = task.reset()
        fell = np.zeros(envs, bool)
        for _ in range(steps):
            out = task.step(walker(obs))
            fell |= out.terminated
            obs = out.obs
    finally:
        task.close()
    return int(fell.sum())


def test_g1_soles_suit_the_heightfield():
    # The model's 5 mm sole spheres sank up to 1.2 cm into the heightfield and met its prisms' side faces: the flat
    # walker (0 falls on the plane) fell in every 10 s episode on flat heightfield ground (8 of 8 by 2.2 s). The rough
    # task's 2 cm spheres, centres raised so that their lowest points stay where the 5 mm ones had them, keep it up
    # (0 of 140 in 10 s); the stiffer terrain contact alone did not (62%).
    flat = tasks.make("g1_walk_flat", 1, seed=0, overrides={"domain_randomization": False})
    rough = tasks.make("g1_walk_rough", 1, seed=0, overrides={"domain_randomization": False})
    try:
        lowest = [np.sort([m.geom_pos[g][2] - m.geom_size[g][0] for g in t.foot_geoms(m)]) for t, m in
                  ((flat, flat.model), (rough, rough.model))]
        np.testing.assert_allclose(lowest[0], lowest[1], atol=1e-9)
        assert {float(rough.model.geom_size[g][0]) for g in rough.foot_geoms(rough.model)} == {0.02}
        assert rough.init_qpos[2] == pytest.approx(flat.init_qpos[2])
    finally:
        flat.close()
        rough.close()
    assert _g1_walker_falls({}) == 0
    assert _g1_walker_falls({"sole_radius": 0.0, "terrain_solref": ()}) >= 3
