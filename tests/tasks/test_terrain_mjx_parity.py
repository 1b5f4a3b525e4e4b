"""The rough tasks' shared math on jax under ``jax.jit`` (what an MJX variant would run) against the numpy the CPU
tasks run: ground heights, the height scan, yaw, the terrain curriculum, asked distances and the command
curriculum, on the default Go1 terrain and random robots all over it (off the map too)."""

from __future__ import annotations

import numpy as np
import pytest

import tasks
from tasks import curriculum, rough, terrain

jax = pytest.importorskip("jax")
jnp = jax.numpy


@pytest.fixture(scope="module")
def grid():
    config = rough.terrain_config(tasks.default_config("go1_joystick_rough"))
    return terrain.build(config)


def test_heights_and_scan_match_on_jax(grid):
    rng = np.random.default_rng(0)
    n = 64
    x_max, y_max = grid.extent
    pos = np.stack([rng.uniform(-12, x_max + 12, n), rng.uniform(-12, y_max + 12, n), rng.uniform(0, 2, n)], 1)
    angles = rng.uniform(-np.pi, np.pi, n)
    quat = np.stack([np.cos(angles / 2), np.zeros(n), np.zeros(n), np.sin(angles / 2)], 1)
    points = terrain.scan_points()
    cpu = grid.sampler()
    dev = {**cpu, "heights": jnp.asarray(cpu["heights"], jnp.float32)}

    @jax.jit
    def on_device(pos, quat):
        yaw = terrain.yaw_from_quat(quat)
        return (terrain.ground_height(dev, pos[:, 0], pos[:, 1]), yaw,
                terrain.height_scan(dev, pos, yaw, jnp.asarray(points, jnp.float32)))

    heights, yaw, scan = on_device(jnp.asarray(pos, jnp.float32), jnp.asarray(quat, jnp.float32))
    np.testing.assert_allclose(yaw, terrain.yaw_from_quat(quat), atol=1e-5)
    np.testing.assert_allclose(heights, terrain.ground_height(cpu, pos[:, 0], pos[:, 1]), atol=1e-6)
    expected = terrain.height_scan(cpu, pos, terrain.yaw_from_quat(quat), points)
    # float32 positions can move a point across a sample boundary (0.1 m apart): compare where none lies within
    # 1e-4 m of one, and require that to be nearly all of them
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    px = pos[:, :1] + c * points[None, :, 0] - s * points[None, :, 1]
    py = pos[:, 1:2] + s * points[None, :, 0] + c * points[None, :, 1]
    clear = np.ones(px.shape, bool)
    for v in (px, py):
        frac = (v + cpu["border"]) / cpu["scale"]
        clear &= np.abs(frac - np.round(frac)) > 1e-3
    assert clear.mean() > 0.97 and np.ptp(expected) > 0.5
    np.testing.assert_allclose(np.asarray(scan)[clear], expected[clear], atol=1e-5)


def test_curricula_match_on_jax():
    rng = np.random.default_rng(1)
    n = 200
    levels = rng.integers(0, 10, n)
    dist = rng.uniform(0, 8, n)
    path0, heading0, steps = rng.uniform(-15, 15, (n, 2)), rng.uniform(-4, 4, n), rng.integers(0, 1001, n)
    command = rng.uniform(-1.5, 1.5, (n, 3))
    draws = rng.integers(0, 10, n)
    path, _ = curriculum.advance_commanded_path(path0, heading0, command, 0.02)
    asked = curriculum.asked_distance(path, steps, 1000)
    expected = curriculum.next_levels(levels, dist, asked, 8.0, 10, draws)
    assert {-1, 0, 1} <= set(np.clip(expected - levels, -1, 1)) and (expected >= 0).all()

    @jax.jit
    def on_device(levels, dist, path, heading, command, steps, draws):
        path, heading = curriculum.advance_commanded_path(path, heading, command, 0.02)
        asked = curriculum.asked_distance(path, steps, 1000)
        return asked, curriculum.next_levels(levels, dist, asked, 8.0, 10, draws)

    floats = (jnp.asarray(a, jnp.float32) for a in (dist, path0, heading0, command))
    got_asked, got = on_device(jnp.asarray(levels), *floats, jnp.asarray(steps), jnp.asarray(draws))
    np.testing.assert_allclose(got_asked, asked, rtol=1e-5)
    np.testing.assert_array_equal(got, expected)
    frac = np.array([0.5, 0.9, 1.0])
    for tracking in (0.79, 0.8):
        dev = jax.jit(curriculum.widen_commands)(jnp.asarray(frac), jnp.ones(3), jnp.full(3, 0.2), tracking)
        np.testing.assert_allclose(dev, curriculum.widen_commands(frac, np.ones(3), np.full(3, 0.2), tracking))
    lv, cols = jax.jit(curriculum.initial_cells, static_argnums=(0, 1))(8, 7, jnp.asarray(draws[:8]))
    np.testing.assert_array_equal(cols, curriculum.initial_cells(8, 7, draws[:8])[1])
