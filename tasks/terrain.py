"""Rough terrain for the walking tasks: a legged_gym-style grid of heightfield cells, built once per worker.

The terrain (Rudin et al. 2021, legged_gym's ``terrain.py``, rebuilt here) is a grid of square cells:
rows are difficulty levels (row 0 easiest), columns terrain types (``TerrainConfig.columns``: one type per
column; repeat a type to give it more columns). Around the grid lies a flat border so no robot walks off.
Everything is pure numpy and deterministic from ``TerrainConfig.seed`` (each cell draws from its own
``default_rng([seed, row, column])``, so a cell does not change when columns are added): every worker, and the MJX
variants, build the same terrain from the same config.

Coordinates: ``heights [nx, ny]`` samples the ground at ``x = i * horizontal_scale - border``, ``y = j *
horizontal_scale - border`` (metres, world frame), so the world origin is the grid's inner corner and cell
(level r, column c) spans ``[r * cell_size, (r + 1) * cell_size) x [c * cell_size, (c + 1) * cell_size)``; its
origin (``Terrain.origins [levels, columns, 3]``) is the cell's centre at the highest ground within 1 m of it
(legged_gym's rule), where the robots of that cell start.

Types (``difficulty = level / (levels - 1)`` in [0, 1] interpolates each config range ``(easy, hard)``); a cell's
height is measured from the border's ground (0):

* ``rough``: uniform random heights of +-amplitude (``rough_height``) drawn every ``rough_scale`` metres and
  interpolated bilinearly (legged_gym's ``random_uniform_terrain``).
* ``slope_up`` / ``slope_down``: a pyramid of constant gradient ``slope`` (rise over run) from the cell's edge
  to a flat central ``platform`` (square, ``platform`` metres wide): ``slope_down`` has the platform on top (the
  robot walks down leaving it), ``slope_up`` is the inverted pyramid (a pit: the robot walks up). Deviation:
  legged_gym's pyramid is the product ``x * y`` of two tents, whose gradient varies; here ``h = slope * (cell/2 -
  max(|dx|, |dy|))`` has the stated gradient everywhere on the sloped part.
* ``rough_slope``: ``slope_down`` plus ``rough_slope_noise`` of the rough pattern (legged_gym's rough slope).
* ``stairs_up`` / ``stairs_down``: square rings of width ``step_width``, each one ``step_height`` higher (down:
  towards the centre, up: towards the edge) up to the central platform (legged_gym's ``pyramid_stairs_terrain``;
  its negative step height is ``stairs_up``).
* ``obstacles``: ``obstacle_count`` rectangles with sides in ``obstacle_size`` metres at heights drawn from
  (-h, -h/2, h/2, h), ``h = obstacle_height``, the central platform flat at 0 (``discrete_obstacles_terrain``).

``add_to_spec`` turns the height map into a MuJoCo ``hfield`` plus a geom that replaces the scene's floor plane
(keeping its name, contact parameters and contact pairs, so foot-contact sensors and floor-friction domain
randomisation work unchanged). ``ground_height`` reads the map at world points (legged_gym's sampler: the
minimum of the sample at or below the point and its +x and +y neighbours), ``highest_ground`` the highest sample
near a point (spawn heights) and ``height_scan`` is legged_gym's grid of points around the base, all written against
the array-API shim so the MJX variants (``tasks/mjx_rough.py``) run them.

Memory: MuJoCo keeps the heightfield in the model as float32, and the CPU tasks copy the model per env for
domain randomisation, so each env holds ``nx * ny * 4`` bytes (the default grid: ~3 MB per env).
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from unilab_jax import xp as shim

TYPES = ("rough", "slope_up", "slope_down", "rough_slope", "stairs_up", "stairs_down", "obstacles")


@dataclasses.dataclass(frozen=True)
class TerrainConfig:
    """The terrain grid. Ranges are ``(level 0, top level)`` values; ``difficulty`` interpolates between them."""

    levels: int = 10
    columns: tuple[str, ...] = TYPES
    cell_size: float = 8.0  # metres (square cells)
    border: float = 10.0  # metres of flat ground around the grid
    horizontal_scale: float = 0.1  # metres between height samples
    seed: int = 0
    platform: float = 3.0  # metres: flat centre of the slope, stairs and obstacle cells
    rough_height: tuple[float, float] = (0.02, 0.1)  # +- amplitude of ``rough``
    rough_scale: float = 0.2  # metres between the random heights that are interpolated
    rough_slope_noise: float = 0.05  # +- amplitude of the noise on ``rough_slope``
    slope: tuple[float, float] = (0.0, 0.4)  # rise over run
    step_width: float = 0.31
    step_height: tuple[float, float] = (0.05, 0.23)
    obstacle_height: tuple[float, float] = (0.05, 0.25)
    obstacle_size: tuple[float, float] = (1.0, 2.0)
    obstacle_count: int = 20

    def __post_init__(self):
        unknown = [t for t in self.columns if t not in TYPES]
        if unknown:
            raise ValueError(f"unknown terrain types {unknown}; choose from {TYPES}")
        if self.levels < 1 or not self.columns:
            raise ValueError("a terrain needs at least one level and one column")
        if self.horizontal_scale <= 0 or self.cell_size < 2 * self.horizontal_scale or self.border < 0:
            raise ValueError("terrain sizes must be positive, cells at least two samples wide")
        if not 0 <= self.platform <= self.cell_size:
            raise ValueError(f"platform {self.platform} must lie in [0, cell_size]")


def difficulty(level: int, levels: int) -> float:
    """Level in [0, 1]: 0 on the first row, 1 on the last (a single row is difficulty 0)."""
    return level / (levels - 1) if levels > 1 else 0.0


def _lerp(bounds: tuple[float, float], t: float) -> float:
    return bounds[0] + (bounds[1] - bounds[0]) * t


# --------------------------------------------------------------------------------------------------
# Cells: [n, n] height arrays, sample k of an axis at k * horizontal_scale from the cell's corner
# --------------------------------------------------------------------------------------------------
def _edge_distance(n: int, hs: float) -> np.ndarray:
    """[n, n] distance of each sample from the cell's boundary square, ``cell/2 - max(|dx|, |dy|)``."""
    half = n * hs / 2
    d = np.abs(np.arange(n) * hs - half)
    return half - np.maximum(d[:, None], d[None, :])


def pyramid_slope(n: int, hs: float, slope: float, platform: float) -> np.ndarray:
    """Heights rising at ``slope`` from 0 at the cell's edge to a flat central square ``platform`` wide
    (negative ``slope``: an inverted pyramid, the pit of ``slope_up``)."""
    e = _edge_distance(n, hs)
    top = n * hs / 2 - platform / 2
    return slope * np.minimum(e, top)


def pyramid_stairs(n: int, hs: float, step_width: float, step_height: float, platform: float) -> np.ndarray:
    """Square rings ``step_width`` wide, each ``step_height`` above the one outside it (the outermost at 0),
    up to a central square at least ``platform`` wide (negative ``step_height``: a pit of stairs)."""
    e = _edge_distance(n, hs)
    steps = max(0, math.floor((n * hs / 2 - platform / 2) / step_width + 1e-9))
    return step_height * np.minimum(np.floor(e / step_width + 1e-9), steps)


def random_rough(n: int, hs: float, amplitude: float, scale: float, rng: np.random.Generator) -> np.ndarray:
    """Uniform heights in [-amplitude, amplitude] drawn on a grid ``scale`` metres apart covering the cell,
    interpolated bilinearly to the cell's samples."""
    k = max(2, math.ceil(n * hs / scale) + 1)
    coarse = rng.uniform(-amplitude, amplitude, size=(k, k))
    u = np.arange(n) * hs / scale  # sample positions in coarse-grid units
    i0 = np.minimum(np.floor(u).astype(np.int64), k - 2)
    f = u - i0
    rows = coarse[i0] * (1 - f)[:, None] + coarse[i0 + 1] * f[:, None]  # [n, k]
    return rows[:, i0] * (1 - f)[None, :] + rows[:, i0 + 1] * f[None, :]


def obstacles(n: int, hs: float, height: float, size: tuple[float, float], count: int, platform: float,
              rng: np.random.Generator) -> np.ndarray:
    """``count`` rectangles (sides U(size) metres) at heights drawn from (-h, -h/2, h/2, h), a flat centre."""
    out = np.zeros((n, n))
    lo, hi = (max(1, round(s / hs)) for s in size)
    levels = np.array([-height, -height / 2, height / 2, height])
    for _ in range(count):
        wx, wy = rng.integers(lo, hi + 1, size=2)
        i, j = rng.integers(0, max(1, n - wx)), rng.integers(0, max(1, n - wy))
        out[i : i + wx, j : j + wy] = rng.choice(levels)
    out[_edge_distance(n, hs) >= n * hs / 2 - platform / 2] = 0.0
    return out


def cell_heights(kind: str, level: int, config: TerrainConfig, rng: np.random.Generator) -> np.ndarray:
    """[n, n] heights of a cell of type ``kind`` at ``level`` (n = cell_size / horizontal_scale)."""
    c = config
    n, hs = round(c.cell_size / c.horizontal_scale), c.horizontal_scale
    t = difficulty(level, c.levels)
    if kind == "rough":
        return random_rough(n, hs, _lerp(c.rough_height, t), c.rough_scale, rng)
    if kind in ("slope_up", "slope_down", "rough_slope"):
        slope = _lerp(c.slope, t) * (-1.0 if kind == "slope_up" else 1.0)
        h = pyramid_slope(n, hs, slope, c.platform)
        return h + random_rough(n, hs, c.rough_slope_noise, c.rough_scale, rng) if kind == "rough_slope" else h
    if kind in ("stairs_up", "stairs_down"):
        step = _lerp(c.step_height, t) * (-1.0 if kind == "stairs_up" else 1.0)
        return pyramid_stairs(n, hs, c.step_width, step, c.platform)
    return obstacles(n, hs, _lerp(c.obstacle_height, t), c.obstacle_size, c.obstacle_count, c.platform, rng)


# --------------------------------------------------------------------------------------------------
# The grid
# --------------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, eq=False)
class Terrain:
    """A built terrain: ``heights [nx, ny]`` (metres, the world frame of the module docstring), ``origins
    [levels, columns, 3]`` (each cell's start point), and the layout constants."""

    config: TerrainConfig
    heights: np.ndarray
    origins: np.ndarray

    @property
    def levels(self) -> int:
        return self.config.levels

    @property
    def columns(self) -> tuple[str, ...]:
        return self.config.columns

    @property
    def extent(self) -> tuple[float, float]:
        """(x, y) size in metres of the cell grid (without the border)."""
        return self.config.levels * self.config.cell_size, len(self.config.columns) * self.config.cell_size

    def sampler(self) -> dict:
        """What ``ground_height`` needs: the height map and its placement."""
        return {"heights": self.heights, "border": self.config.border, "scale": self.config.horizontal_scale}


def build(config: TerrainConfig) -> Terrain:
    """The terrain of ``config``: every cell generated from its own seed, the border flat at 0."""
    c = config
    hs = c.horizontal_scale
    n, b = round(c.cell_size / hs), round(c.border / hs)
    heights = np.zeros((2 * b + c.levels * n, 2 * b + len(c.columns) * n))
    origins = np.zeros((c.levels, len(c.columns), 3))
    near = round(1.0 / hs)  # samples within 1 m of the centre
    for r in range(c.levels):
        for j, kind in enumerate(c.columns):
            cell = cell_heights(kind, r, c, np.random.default_rng([c.seed, r, j]))
            heights[b + r * n : b + (r + 1) * n, b + j * n : b + (j + 1) * n] = cell
            centre = cell[n // 2 - near : n // 2 + near + 1, n // 2 - near : n // 2 + near + 1]
            origins[r, j] = ((r + 0.5) * c.cell_size, (j + 0.5) * c.cell_size, centre.max())
    return Terrain(config=c, heights=heights, origins=origins)


# --------------------------------------------------------------------------------------------------
# MuJoCo
# --------------------------------------------------------------------------------------------------
def add_to_spec(spec: mujoco.MjSpec, terrain: Terrain, floor: str = "floor", hfield: str = "terrain") -> None:
    """Replaces the scene's ``floor`` geom by a heightfield geom of ``terrain`` with the same name and contact
    parameters (friction, priority, condim, solref/solimp, contype/conaffinity, margin, rgba).

    MuJoCo's heightfield data are normalised to [0, 1] over ``size[2]`` metres above the geom's z; data row
    ``k`` is y sample ``k``, so the data is ``heights.T``."""
    h = terrain.heights
    lo, hi = float(h.min()), float(h.max())
    top = max(hi - lo, 1e-6)
    nx, ny = h.shape
    hs, b = terrain.config.horizontal_scale, terrain.config.border
    rx, ry = (nx - 1) * hs / 2, (ny - 1) * hs / 2
    spec.add_hfield(name=hfield, size=[rx, ry, top, 1.0], nrow=ny, ncol=nx,
                    userdata=((h.T - lo) / top).ravel())
    old = spec.geom(floor)
    geom = spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname=hfield, pos=[rx - b, ry - b, lo])
    for attr in ("friction", "priority", "condim", "solref", "solimp", "solmix", "contype", "conaffinity", "margin",
                 "gap", "rgba", "group"):
        setattr(geom, attr, getattr(old, attr))
    spec.delete(old)
    geom.name = floor


# --------------------------------------------------------------------------------------------------
# Reading the map (shim)
# --------------------------------------------------------------------------------------------------
def ground_height(sampler: dict, x, y):
    """Ground height at world points ``x, y`` (any equal shapes): legged_gym's sampler, the minimum of the map
    sample at or below the point (floor of its grid coordinates) and the samples one step +x and +y of it;
    points off the map read its edge."""
    xp = shim.namespace(x, y)
    hmap = sampler["heights"]
    nx, ny = hmap.shape
    scale, border = sampler["scale"], sampler["border"]
    i = xp.clip(xp.astype(xp.floor((x + border) / scale), xp.int32), 0, nx - 2)
    j = xp.clip(xp.astype(xp.floor((y + border) / scale), xp.int32), 0, ny - 2)
    return xp.minimum(xp.minimum(hmap[i, j], hmap[i + 1, j]), hmap[i, j + 1])


def highest_ground(sampler: dict, x, y, radius: float):
    """[n] the highest map sample within ``radius`` (a square) of each point ``x, y [n]``: the samples of every grid
    cell the square touches, both corners included (where a robot's feet may rest)."""
    xp = shim.namespace(x, y)
    hmap, scale, border = sampler["heights"], sampler["scale"], sampler["border"]
    k = math.ceil(radius / scale)
    off = xp.arange(-k, k + 2)
    i = xp.clip(xp.astype(xp.floor((x + border) / scale), xp.int32)[:, None] + off, 0, hmap.shape[0] - 1)
    j = xp.clip(xp.astype(xp.floor((y + border) / scale), xp.int32)[:, None] + off, 0, hmap.shape[1] - 1)
    return xp.max(hmap[i[:, :, None], j[:, None, :]], axis=(1, 2))


def scan_points(nx: int = 17, ny: int = 11, spacing: float = 0.1) -> np.ndarray:
    """[nx * ny, 2] body-frame (x, y) offsets of the scan grid, centred on the base (legged_gym's 17 x 11 points
    at 0.1 m: x in [-0.8, 0.8], y in [-0.5, 0.5]), x-major."""
    px = (np.arange(nx) - (nx - 1) / 2) * spacing
    py = (np.arange(ny) - (ny - 1) / 2) * spacing
    return np.stack(np.meshgrid(px, py, indexing="ij"), axis=-1).reshape(-1, 2)


def height_scan(sampler: dict, base_pos, yaw, points, clip: float = 1.0):
    """[M, P] ground height under each scan point minus the base height, clipped to +-``clip``: the points
    ``points [P, 2]`` turned by the base's ``yaw [M]`` and moved to its ``base_pos [M, 3]`` (legged_gym's
    ``quat_apply_yaw``: the scan follows the heading, not roll or pitch)."""
    xp = shim.namespace(base_pos, yaw)
    c, s = xp.cos(yaw)[:, None], xp.sin(yaw)[:, None]
    x = base_pos[:, 0:1] + c * points[None, :, 0] - s * points[None, :, 1]
    y = base_pos[:, 1:2] + s * points[None, :, 0] + c * points[None, :, 1]
    return xp.clip(ground_height(sampler, x, y) - base_pos[:, 2:3], -clip, clip)


def yaw_from_quat(quat):
    """[M] heading (rotation about world z) of quaternions [M, 4] (w, x, y, z)."""
    xp = shim.namespace(quat)
    w, x, y, z = quat[:, 0], quat[:, 1], quat[:, 2], quat[:, 3]
    return xp.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
