"""Terrain generation, its MuJoCo heightfield, the height sampler and the curricula, checked by hand."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from tasks import curriculum as cur
from tasks import terrain as tr

SMALL = tr.TerrainConfig(levels=3, columns=("stairs_down", "slope_up", "rough", "obstacles"), cell_size=4.0,
                         border=1.0, platform=1.0, step_width=0.3, step_height=(0.05, 0.15), slope=(0.1, 0.3))


def test_stairs_rise_one_step_per_ring_to_the_platform():
    h = tr.pyramid_stairs(80, 0.1, step_width=0.3, step_height=0.1, platform=3.0)
    row = h[40]  # through the centre: edge distance e = 4 - |0.1 j - 4|
    np.testing.assert_allclose(row[:7], [0, 0, 0, 0.1, 0.1, 0.1, 0.2])  # a step every 0.3 m from the edge
    # floor((4 - 1.5) / 0.3) = 8 steps: the platform (within 1.5 m of the centre) stands 0.8 m high
    assert row[23] == pytest.approx(0.7) and row[24] == pytest.approx(0.8) and row[40] == pytest.approx(0.8)
    np.testing.assert_allclose(h, h.T)  # square rings
    pit = tr.pyramid_stairs(80, 0.1, 0.3, -0.1, 3.0)
    np.testing.assert_allclose(pit, -h)


def test_slope_has_its_gradient_and_a_flat_platform():
    h = tr.pyramid_slope(80, 0.1, slope=0.2, platform=3.0)
    np.testing.assert_allclose(np.diff(h[40, :25]), 0.02)  # 0.2 rise over 0.1 m from the edge to the platform
    assert h[40, 0] == 0.0 and h[40, 40] == pytest.approx(0.2 * 2.5)  # top: slope * (4 - 1.5)
    np.testing.assert_allclose(h[25:56, 25:56], 0.5)  # platform: 3 m square around the centre
    np.testing.assert_allclose(np.diff(h[40, 26:55]), 0.0)


def test_rough_stays_within_its_amplitude_and_interpolates():
    rng = np.random.default_rng(0)
    h = tr.random_rough(40, 0.1, amplitude=0.05, scale=0.2, rng=rng)
    assert np.abs(h).max() <= 0.05 and h.std() > 0.01
    # every other sample lies on the 0.2 m grid; the samples between are the mean of their neighbours
    np.testing.assert_allclose(h[1:-1:2, 0], (h[0:-2:2, 0] + h[2::2, 0]) / 2)


def test_obstacles_leave_the_platform_flat_and_use_four_heights():
    h = tr.obstacles(80, 0.1, 0.2, (1.0, 2.0), 20, 3.0, np.random.default_rng(1))
    assert set(np.round(np.unique(h), 6)) <= {-0.2, -0.1, 0.0, 0.1, 0.2}
    np.testing.assert_array_equal(h[25:56, 25:56], 0.0)
    assert (h != 0).mean() > 0.2


def test_grid_layout_border_origins_and_difficulty():
    t = tr.build(SMALL)
    n, b = 40, 10
    assert t.heights.shape == (2 * b + 3 * n, 2 * b + 4 * n)
    # border flat at 0 on every side
    for edge in (t.heights[:b], t.heights[-b:], t.heights[:, :b], t.heights[:, -b:]):
        np.testing.assert_array_equal(edge, 0.0)
    # origins: cell centres; z the highest ground within 1 m of the centre
    np.testing.assert_allclose(t.origins[:, :, 0], [[2.0] * 4, [6.0] * 4, [10.0] * 4])
    np.testing.assert_allclose(t.origins[:, :, 1], [[2.0, 6.0, 10.0, 14.0]] * 3)
    # stairs_down at level r: step 0.05 + 0.05 r, floor((2 - 0.5) / 0.3) = 5 steps up to the platform
    np.testing.assert_allclose(t.origins[:, 0, 2], [0.25, 0.5, 0.75])
    # slope_up (a pit, gradient 0.3 at the top level): its platform at -0.3 * 1.5, 1 m from the centre -0.3
    assert t.origins[2, 1, 2] == pytest.approx(-0.3)
    assert t.heights[b + 2 * n + 20, b + n + 20] == pytest.approx(-0.45)
    # cell (level 1, stairs_down) sits at x in [4, 8), y in [0, 4): its platform top at the origin
    assert t.heights[b + n + 20, b + 20] == pytest.approx(0.5)
    assert tr.difficulty(0, 3) == 0.0 and tr.difficulty(2, 3) == 1.0 and tr.difficulty(0, 1) == 0.0


def test_same_seed_same_terrain_other_seed_other_terrain():
    a, b = tr.build(SMALL), tr.build(SMALL)
    np.testing.assert_array_equal(a.heights, b.heights)
    c = tr.build(tr.TerrainConfig(**{**SMALL.__dict__, "seed": 1}))
    assert not np.array_equal(a.heights, c.heights)
    # a cell's content depends on its seed, level and column, not on the cells around it
    wider = tr.build(tr.TerrainConfig(**{**SMALL.__dict__, "columns": (*SMALL.columns, "rough")}))
    np.testing.assert_array_equal(wider.heights[:, :170], a.heights[:, :170])


def test_bad_terrain_config_is_refused():
    with pytest.raises(ValueError, match="unknown terrain types"):
        tr.TerrainConfig(columns=("lava",))
    with pytest.raises(ValueError, match="platform"):
        tr.TerrainConfig(platform=9.0)


def _floor_spec() -> mujoco.MjSpec:
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], priority=1,
                            condim=3, friction=[0.7, 0.01, 0.001])
    return spec


def test_heightfield_in_the_compiled_model_is_the_height_map():
    t = tr.build(SMALL)
    spec = _floor_spec()
    tr.add_to_spec(spec, t)
    m = spec.compile()
    g = m.geom("floor")
    assert g.type == mujoco.mjtGeom.mjGEOM_HFIELD and m.ngeom == 1
    assert g.priority == 1 and g.condim == 3 and g.friction[0] == pytest.approx(0.7)  # the floor's parameters
    nx, ny = t.heights.shape
    assert (m.hfield_nrow[0], m.hfield_ncol[0]) == (ny, nx)
    data = m.hfield_data.reshape(ny, nx) * m.hfield_size[0, 2] + g.pos[2]
    np.testing.assert_allclose(data, t.heights.T, atol=2e-6)  # float32 storage
    # and where it stands: a ray down from above each probed sample hits the map's height there
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    gid = np.array([-1], np.int32)
    rng = np.random.default_rng(0)
    for i, j in zip(rng.integers(1, nx - 1, 20), rng.integers(1, ny - 1, 20), strict=True):
        x, y = i * 0.1 - 1.0, j * 0.1 - 1.0
        dist = mujoco.mj_ray(m, d, np.array([x, y, 5.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, gid)
        assert 5.0 - dist == pytest.approx(t.heights[i, j], abs=1e-5)


def test_ground_height_is_the_min_of_three_neighbours():
    hmap = np.array([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0], [6.0, 7.0, 8.0]])
    s = {"heights": hmap, "border": 0.5, "scale": 0.5}
    # (x, y) = (0.3, 0.1): grid (1.6, 1.2) -> sample (1, 1); min(h[1,1], h[2,1], h[1,2]) = 4
    assert tr.ground_height(s, np.array([0.3]), np.array([0.1]))[0] == 4.0
    # (-0.5, -0.5): sample (0, 0) -> min(0, 3, 1) = 0; far off the map: clipped to sample (1, 1)
    np.testing.assert_array_equal(tr.ground_height(s, np.array([-0.5, 9.0]), np.array([-0.5, 9.0])), [0.0, 4.0])


def test_height_scan_turns_with_the_heading():
    hmap = np.zeros((40, 40))
    hmap[:, 25:] = 0.2  # a 0.2 m step along y >= 0.5 (border 2, scale 0.1)
    s = {"heights": hmap, "border": 2.0, "scale": 0.1}
    pts = tr.scan_points(3, 3, 0.5)  # x in (-0.5, 0, 0.5) x y in (-0.5, 0, 0.5)
    np.testing.assert_allclose(pts[:3], [[-0.5, -0.5], [-0.5, 0.0], [-0.5, 0.5]])
    base = np.array([[0.0, 0.0, 0.3], [0.0, 0.0, 0.3]])
    scan = tr.height_scan(s, base, np.array([0.0, math.pi / 2]), pts).reshape(2, 3, 3)
    # heading 0: the body's +y points at the step (the y = +0.5 column)
    np.testing.assert_allclose(scan[0], [[-0.3, -0.3, -0.1]] * 3, atol=1e-12)
    # heading 90 degrees: the body's +x points at +y, so the x = +0.5 row reads the step
    np.testing.assert_allclose(scan[1], [[-0.3] * 3, [-0.3] * 3, [-0.1] * 3], atol=1e-12)
    assert tr.height_scan(s, base + [0, 0, 5.0], np.zeros(2), pts).min() == -1.0  # clipped
    assert tr.yaw_from_quat(np.array([[math.cos(0.4), 0.0, 0.0, math.sin(0.4)]]))[0] == pytest.approx(0.8)


# --------------------------------------------------------------------------------------------------
# Curricula
# --------------------------------------------------------------------------------------------------
def test_terrain_curriculum_promotes_demotes_and_wraps():
    levels = np.array([0, 3, 3, 0, 9, 5])
    distance = np.array([4.5, 4.5, 1.0, 0.5, 6.0, 2.0])  # cell 8 m: promoted beyond 4 m
    asked = np.array([10.0, 10.0, 3.0, 3.0, 1.0, 4.0])  # demoted below half of it
    random = np.array([7, 7, 7, 7, 2, 7])
    new = cur.next_levels(levels, distance, asked, 8.0, 10, random)
    # up; up (promotion wins over demotion); down; stays at 0; top solved -> random 2; 2.0 is not < 2.0: stays
    np.testing.assert_array_equal(new, [1, 4, 2, 0, 2, 5])


def test_commanded_path_and_asked_distance():
    dt, n = 0.001, 1000  # 1 s of commands
    path, heading = np.zeros((3, 2)), np.zeros(3)
    # straight at 1 m/s; sideways at 0.5 m/s; 1 m/s forward while turning pi/2 rad/s: a quarter circle of radius
    # 2/pi m, ending at (2/pi, 2/pi)
    command = np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 0.0], [1.0, 0.0, np.pi / 2]])
    for _ in range(n):
        path, heading = cur.advance_commanded_path(path, heading, command, dt)
    np.testing.assert_allclose(heading, [0.0, 0.0, np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(path, [[1.0, 0.0], [0.0, 0.5], [2 / np.pi, 2 / np.pi]], atol=1e-3)
    # reach scaled from the 1000 steps walked to a 4000-step episode; an episode of 0 steps asks for nothing
    np.testing.assert_allclose(cur.asked_distance(path, np.array([n, n, n]), 4 * n),
                               [4.0, 2.0, 4 * np.hypot(2 / np.pi, 2 / np.pi)], rtol=1e-3)
    assert cur.asked_distance(np.zeros((1, 2)), np.array([0]), 1000)[0] == 0.0


def test_a_robot_that_follows_a_turning_command_is_not_demoted():
    """A full circle in 20 s (1 m/s, 2 pi / 20 rad/s) asks for no distance, however long its path (20 m): the robot
    that rode it back to its start stays; one that stood still on a straight command is demoted."""
    steps, dt = 1000, 0.02
    path, heading = np.zeros((2, 2)), np.zeros(2)
    command = np.array([[1.0, 0.0, 2 * np.pi / 20], [1.0, 0.0, 0.0]])
    for _ in range(steps):
        path, heading = cur.advance_commanded_path(path, heading, command, dt)
    asked = cur.asked_distance(path, np.array([steps, steps]), steps)
    np.testing.assert_allclose(asked, [0.0, 20.0], atol=1e-9)
    new = cur.next_levels(np.array([3, 3]), np.array([0.1, 0.1]), asked, 8.0, 10, np.array([0, 0]))
    np.testing.assert_array_equal(new, [3, 2])


def test_initial_cells():
    levels, cols = cur.initial_cells(6, 4, np.array([0, 1, 2, 0, 1, 2]))
    np.testing.assert_array_equal(cols, [0, 0, 1, 2, 2, 3])  # floor(i * 4 / 6)
    np.testing.assert_array_equal(levels, [0, 1, 2, 0, 1, 2])


def test_command_curriculum_widens_when_tracking_is_good():
    cur_range, final, step = np.array([0.5, 0.3, 0.5]), np.array([1.5, 0.8, 1.2]), np.array([0.5, 0.5, 0.5])
    np.testing.assert_allclose(cur.widen_commands(cur_range, final, step, 0.79), cur_range)
    np.testing.assert_allclose(cur.widen_commands(cur_range, final, step, 0.8), [1.0, 0.8, 1.0])
    np.testing.assert_allclose(cur.widen_commands(np.array([1.0, 0.8, 1.0]), final, step, 0.9), final)
