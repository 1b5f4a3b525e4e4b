"""What every rough-terrain walking task adds to its flat task: the terrain, robots placed on their cells, the
terrain and command curricula, the height scan, the per-episode terrain metrics and the evaluation on hard cells.

A task composes one ``TerrainState`` (``tasks/go1_rough.py``: ``go1_joystick_rough``) and calls it from its hooks:

* model: ``add_to_spec`` swaps the scene's floor plane for the terrain's heightfield (``tasks/terrain.py``);
* reset: ``place`` moves new episodes to their cell's origin (plus the task's own xy jitter) at the standing
  height above the highest ground within ``spawn_radius`` of any foot, so the feet start on the surface, not in it;
* each step: ``record_step`` advances each env's commanded path (``curriculum.advance_commanded_path``: where a
  robot following its commands exactly would be) and its path measure (``curriculum.advance_walked_path``: the
  distance made along the command, the commanded path's length) and sums its velocity-tracking reward;
* episode end (auto-reset): ``episode_end`` applies legged_gym's terrain curriculum (``curriculum.next_levels``:
  by ``curriculum_distance``, the distance from the cell's origin vs half a cell and vs half of the commanded path's
  reach, or the distance made along the command vs half a cell and vs half of the commanded path) and, on, the command
  curriculum (``command_fraction`` of the final command ranges widens by ``command_step`` once the episodes that
  ended since the last update, at least ``num_envs`` of them, tracked at ``command_threshold`` of the tracking
  reward's maximum); envs that diverged (MuJoCo instability) keep their level;
* observation: ``scan`` is the height scan (``terrain.height_scan``: 17 x 11 points, 0.1 m apart, around the base,
  turned with its heading), appended to the critic observation and, with ``perceptive``, to the actor's;
* truncation: ``off_map`` ends episodes of robots within 1 m of the map's edge, ``out_of_band`` those of robots
  whose base left ``base_height_band`` above the ground under it (through the heightfield, or thrown);
* metrics: ``episode_metrics`` (``METRICS``: the ended episodes' ``terrain_level`` and the level histogram
  ``terrain_level_<k>``, logged by the trainer as ``episode/...``); ``TerrainEval``, the evaluation tracker:
  env i on column ``i mod columns`` at a level of the upper half (``levels // 2`` and above), curricula frozen,
  full command ranges; it reports the walking metric's numbers overall, the lowest evaluated and the top level,
  the rough-terrain walking criterion ``rough_terrain_walking`` (1/0: ``metrics.WALKING.met_on_rough``, the walking
  criterion met on levels >= half the top level) and per terrain type (``walking_<type>`` 1/0,
  ``tracking_error_<type>``, ``fall_rate_<type>``).

Each worker keeps its own curricula (levels of its envs, command fraction); every worker builds the same terrain
from ``terrain_seed``. The initial levels come from the task seed: U{0, ..., max_init_level}, or from
``init_level_weights`` (a resumed run: the level distribution its robots stopped at, ``resumed_level_weights``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from typing import Any

import mujoco
import numpy as np

from tasks import base, curriculum, go1_math, terrain
from unilab_jax.metrics import WALKING


@dataclasses.dataclass(frozen=True)
class RoughConfig:
    """The rough-terrain fields of a task config (terrain ranges: (level 0, top level), see ``terrain.py``)."""

    terrain_levels: int = 10
    terrain_columns: tuple[str, ...] = terrain.TYPES
    terrain_cell_size: float = 8.0
    terrain_border: float = 10.0
    terrain_scale: float = 0.1
    terrain_seed: int = 0
    terrain_platform: float = 3.0
    terrain_rough_height: tuple[float, float] = (0.02, 0.1)
    terrain_slope: tuple[float, float] = (0.0, 0.4)
    terrain_step_width: float = 0.31
    terrain_step_height: tuple[float, float] = (0.05, 0.23)
    terrain_obstacle_height: tuple[float, float] = (0.05, 0.25)
    max_init_level: int = 4
    # weights over the levels (one per level) for the initial levels instead of U{0, ..., max_init_level}: a run
    # resumed from its checkpoint starts its robots where its population stood (``resumed_level_weights``, set by
    # ``--resume``), since the workers' curricula are not in the checkpoint
    init_level_weights: tuple[float, ...] = ()
    terrain_curriculum: bool = True
    # what the terrain curriculum measures (tasks/curriculum.py): "displacement", legged_gym's (the base's distance
    # from its cell's origin against half a cell, and against half of the commanded path's reach), or "path" (the
    # distance made along the commanded direction against half a cell, and against half of the commanded path's
    # length), for tasks that hold one yaw-rate command a whole episode (circular paths: Go2, G1)
    curriculum_distance: str = "displacement"
    # the heightfield's contact solref; () keeps the floor plane's (0.02, 1). A foot that sinks deeper than its
    # collision sphere's radius meets the side faces of the heightfield's prisms (horizontal contact normals on flat
    # ground: docs/TERRAIN.md); the stiffer contact (time constant 0.01 s, >= 2 physics steps of every task here)
    # makes that rarer
    terrain_solref: tuple[float, ...] = (0.01, 1.0)
    # A base whose height above the ground under it leaves this band (metres) has fallen through the heightfield or
    # been thrown by a contact that came too late, neither of which MuJoCo flags: its episode is truncated, as at the
    # map's edge (a task's own termination, e.g. a base below ``min_base_height``, wins). In a Go2 run a robot flew
    # on for the rest of its episode: its penalties, 1e7-1e8, set FlashSAC's reward scale 7e4 times higher and the
    # policy collapsed (docs/TERRAIN.md). Standing, lying, stepping off the tallest terrain or jumping stays inside.
    base_height_band: tuple[float, float] = (-0.5, 3.0)
    spawn_radius: float = 0.05  # metres around each foot whose highest ground sets the spawn height
    perceptive: bool = False  # True: the actor sees the height scan too (the critic always does)
    scan_shape: tuple[int, int] = (17, 11)
    scan_spacing: float = 0.1
    command_curriculum: bool = False
    command_start: tuple[float, float, float] = (0.5, 0.5, 0.5)  # fraction of the final (vx, vy, yaw) ranges
    command_step: tuple[float, float, float] = (0.1, 0.1, 0.1)
    command_threshold: float = 0.8


@dataclasses.dataclass(frozen=True)
class SmallQuadrupedRough(RoughConfig):
    """``RoughConfig``'s terrain sized for a small quadruped (Go1, Go2: ~0.3 m legs)."""

    terrain_rough_height: tuple[float, float] = (0.01, 0.06)
    terrain_step_width: float = 0.25
    terrain_step_height: tuple[float, float] = (0.02, 0.14)
    terrain_obstacle_height: tuple[float, float] = (0.02, 0.14)


def check_level_weights(c: RoughConfig) -> None:
    """ValueError unless ``init_level_weights`` is () or one weight >= 0 per level with a positive sum."""
    w = c.init_level_weights
    if w and (len(w) != c.terrain_levels or min(w) < 0 or sum(w) <= 0):
        raise ValueError(f"init_level_weights must be () or {c.terrain_levels} weights >= 0 with a positive sum, "
                         f"got {w}")


def level_probabilities(c: RoughConfig) -> np.ndarray:
    """``init_level_weights`` normalised (float64, summing to 1)."""
    w = np.asarray(c.init_level_weights, dtype=np.float64)
    return w / w.sum()


def resumed_level_weights(metrics_path: str, num_levels: int, window_s: float) -> tuple[float, ...]:
    """The level distribution of a run's robots when it stopped: the mean of its training rows' level histogram
    (``episode/terrain_level_<k>``, the share of the episodes ended since the previous row) over the last
    ``window_s`` seconds of ``time/wall_s`` (the caller passes one episode's duration: every robot ends about one in
    it); () when the file holds no such row or another number of levels."""
    keys = [f"episode/terrain_level_{k}" for k in range(num_levels)]
    rows = []
    if os.path.exists(metrics_path):
        with open(metrics_path) as f:
            for line in f:
                r = json.loads(line)
                if "time/wall_s" in r and keys[0] in r:
                    rows.append(r)
    if not rows or f"episode/terrain_level_{num_levels}" in rows[-1] or keys[-1] not in rows[-1]:
        return ()
    end = max(r["time/wall_s"] for r in rows)
    last = [r for r in rows if r["time/wall_s"] >= end - window_s]
    mean = [sum(r[k] for r in last) / len(last) for k in keys]
    return tuple(round(m, 4) for m in mean) if sum(mean) > 0 else ()


def out_of_band(base_height: Any, band: tuple[float, float]) -> Any:
    """[M] bool: base heights above the ground (numpy or jax) outside ``band = (low, high)``."""
    return (base_height < band[0]) | (base_height > band[1])


def terrain_config(c: RoughConfig) -> terrain.TerrainConfig:
    return terrain.TerrainConfig(
        levels=c.terrain_levels, columns=tuple(c.terrain_columns), cell_size=c.terrain_cell_size,
        border=c.terrain_border, horizontal_scale=c.terrain_scale, seed=c.terrain_seed, platform=c.terrain_platform,
        rough_height=c.terrain_rough_height, slope=c.terrain_slope, step_width=c.terrain_step_width,
        step_height=c.terrain_step_height, obstacle_height=c.terrain_obstacle_height)


class TerrainState:
    """The terrain and the per-env curriculum state of one task instance (see the module docstring)."""

    def __init__(self, config: RoughConfig, num_envs: int, seed: int, ctrl_dt: float, episode_length: int):
        c = config
        if not 0 <= c.max_init_level < c.terrain_levels:
            raise ValueError(f"max_init_level {c.max_init_level} must lie in [0, terrain_levels)")
        check_level_weights(c)
        if c.curriculum_distance not in ("displacement", "path"):
            raise ValueError(f"curriculum_distance must be 'displacement' or 'path', got {c.curriculum_distance!r}")
        if len(c.terrain_solref) not in (0, 2):
            raise ValueError(f"terrain_solref must be () or (timeconst, dampratio), got {c.terrain_solref}")
        self.config, self.num_envs = c, num_envs
        self.terrain = terrain.build(terrain_config(c))
        self.sampler = self.terrain.sampler()
        self.episode_length, self.ctrl_dt = episode_length, ctrl_dt
        self._rng = np.random.default_rng([seed, 0x7E55A1])
        ncol = len(self.terrain.columns)
        draws = (self._rng.choice(c.terrain_levels, size=num_envs, p=level_probabilities(c))
                 if c.init_level_weights else self._rng.integers(0, c.max_init_level + 1, size=num_envs))
        self.levels, self.cols = curriculum.initial_cells(num_envs, ncol, draws)
        self.points = terrain.scan_points(*c.scan_shape, c.scan_spacing)
        # this episode's commanded path (curriculum.advance_commanded_path): its displacement and heading
        self.commanded = np.zeros((num_envs, 2))
        self.commanded_heading = np.zeros(num_envs)
        # the path measure (curriculum.advance_walked_path): distance made along the command, commanded path length
        self.walked = np.zeros(num_envs)
        self.asked_path = np.zeros(num_envs)
        self.tracking_sum = np.zeros(num_envs)
        self.command_fraction = np.array(c.command_start if c.command_curriculum else (1.0, 1.0, 1.0))
        self._cmd_tracking, self._cmd_episodes = 0.0, 0
        self.frozen = False  # evaluation: cells fixed, curricula off
        x_max, y_max = self.terrain.extent
        margin = c.terrain_border - 1.0
        self.bounds = (-margin, x_max + margin, -margin, y_max + margin)
        self.metric_names = ("terrain_level", *(f"terrain_level_{k}" for k in range(c.terrain_levels)))

    @property
    def scan_dim(self) -> int:
        return self.points.shape[0]

    def add_to_spec(self, spec: Any) -> None:
        terrain.add_to_spec(spec, self.terrain)
        if self.config.terrain_solref:
            spec.geom("floor").solref = list(self.config.terrain_solref)

    def origins(self, idx: np.ndarray) -> np.ndarray:
        """[n, 3] the cell origins of envs ``idx``."""
        return self.terrain.origins[self.levels[idx], self.cols[idx]]

    def place(self, qpos: np.ndarray, idx: np.ndarray, standing_height: float, feet: np.ndarray) -> np.ndarray:
        """New episodes' ``qpos [n, nq]`` (free joint first, xy relative to the cell's origin) moved onto the cells
        of envs ``idx``, the base ``standing_height`` above the highest ground within ``spawn_radius`` of any foot
        (``feet [F, 2]``: the feet's body-frame xy in the standing pose, turned with the base's heading): the
        highest foot stands as on flat ground, the others above the ground."""
        qpos = qpos.copy()
        qpos[:, :2] += self.origins(idx)[:, :2]
        yaw = terrain.yaw_from_quat(qpos[:, 3:7])[:, None]
        c, s = np.cos(yaw), np.sin(yaw)
        x = qpos[:, 0:1] + c * feet[None, :, 0] - s * feet[None, :, 1]
        y = qpos[:, 1:2] + s * feet[None, :, 0] + c * feet[None, :, 1]
        top = terrain.highest_ground(self.sampler, x.ravel(), y.ravel(), self.config.spawn_radius).reshape(x.shape)
        qpos[:, 2] = standing_height + top.max(axis=1)
        return qpos

    def scan(self, qpos: np.ndarray) -> np.ndarray:
        """[M, P] the height scan at the bases of ``qpos [M, nq]``."""
        yaw = terrain.yaw_from_quat(qpos[:, 3:7])
        return terrain.height_scan(self.sampler, qpos[:, :3], yaw, self.points)

    def off_map(self, qpos: np.ndarray) -> np.ndarray:
        x0, x1, y0, y1 = self.bounds
        x, y = qpos[:, 0], qpos[:, 1]
        return (x < x0) | (x > x1) | (y < y0) | (y > y1)

    def record_step(self, command: np.ndarray, tracking: np.ndarray, velocity: np.ndarray, yaw: np.ndarray) -> None:
        """Advances each env's commanded path by a control step of ``command`` and the path measure by the base's
        world-frame planar ``velocity [M, 2]`` at ``yaw [M]``, and adds the step's tracking reward (in [0, 1]) to
        its episode sum."""
        self.commanded, self.commanded_heading = curriculum.advance_commanded_path(
            self.commanded, self.commanded_heading, command, self.ctrl_dt)
        self.walked, self.asked_path = curriculum.advance_walked_path(self.walked, self.asked_path, velocity, yaw,
                                                                      command, self.ctrl_dt)
        self.tracking_sum += tracking

    def episode_end(self, idx: np.ndarray, qpos: np.ndarray, steps: np.ndarray, diverged: np.ndarray) -> None:
        """The curricula at the end of the episodes of envs ``idx`` (``qpos [n, nq]`` their last states,
        ``steps [n]`` their lengths, ``diverged [n]`` those MuJoCo reset as unstable), then fresh sums."""
        c = self.config
        if not self.frozen and c.terrain_curriculum:
            ok = idx[~diverged]
            if c.curriculum_distance == "path":
                dist = self.walked[ok]
                asked = curriculum.per_episode(self.asked_path[ok], steps[~diverged], self.episode_length)
            else:
                dist = np.linalg.norm(qpos[~diverged, :2] - self.origins(ok)[:, :2], axis=1)
                asked = curriculum.asked_distance(self.commanded[ok], steps[~diverged], self.episode_length)
            self.levels[ok] = curriculum.next_levels(self.levels[ok], dist, asked, c.terrain_cell_size,
                                                     c.terrain_levels, self._rng.integers(0, c.terrain_levels, ok.size))
        if not self.frozen and c.command_curriculum:
            # per episode: its tracking reward per step of a full episode (legged_gym: a short one scores less)
            self._cmd_tracking += float(self.tracking_sum[idx].sum()) / self.episode_length
            self._cmd_episodes += idx.size
            if self._cmd_episodes >= self.num_envs:
                mean = self._cmd_tracking / self._cmd_episodes
                self.command_fraction = curriculum.widen_commands(self.command_fraction, np.ones(3),
                                                                  np.array(c.command_step), mean, c.command_threshold)
                self._cmd_tracking, self._cmd_episodes = 0.0, 0
        self.commanded[idx] = 0.0
        self.commanded_heading[idx] = 0.0
        self.walked[idx] = 0.0
        self.asked_path[idx] = 0.0
        self.tracking_sum[idx] = 0.0

    def episode_metrics(self, levels: np.ndarray) -> dict[str, np.ndarray]:
        """``{name: [M]}`` of ``metric_names`` for episodes played at ``levels`` (read where they ended)."""
        out = {"terrain_level": levels.astype(np.float32)}
        for k in range(self.config.terrain_levels):
            out[f"terrain_level_{k}"] = (levels == k).astype(np.float32)
        return out

    def freeze_for_evaluation(self) -> None:
        """Env i on column ``i mod columns``, level ``levels // 2 + (i // columns) mod (levels - levels // 2)``;
        curricula off, full command ranges."""
        n, L = len(self.terrain.columns), self.config.terrain_levels
        i = np.arange(self.num_envs)
        self.cols = i % n
        self.levels = L // 2 + (i // n) % (L - L // 2)
        self.command_fraction = np.ones(3)
        self.frozen = True


def foot_points(model: Any, qpos: np.ndarray, geoms: Any) -> np.ndarray:
    """[F, 2] the xy of geoms ``geoms`` (the feet's contact spheres) relative to the base in pose ``qpos``
    (heading 0): the points whose ground sets the spawn height."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    return np.array([data.geom_xpos[g, :2] - qpos[:2] for g in geoms])


class RoughTask:
    """A flat walking task on the terrain: listed before the flat task class (``class Go1JoystickRough(RoughTask,
    Go1JoystickFlat)``), it plugs a ``TerrainState`` into the flat task's hooks (``build_spec``, ``base_states``,
    ``extend_obs``, ``at_limit``, ``_after_physics``, ``_reset_and_observe``).

    The subclass sets ``NAME`` and provides ``foot_geoms(model)`` (the feet's contact spheres) and
    ``command_ranges(fraction)`` (sets the command ranges: the config's times ``fraction [3]``); it reads heights
    above the ground (``base_ground``, ``feet_ground``) where its rewards and terminations read heights, and
    exposes ``command``, ``_s(sensor)`` and ``config.tracking_sigma`` (the tracking reward the command curriculum
    sums)."""

    NAME = ""

    def __init__(self, config: Any, num_envs: int, seed: int):
        self.rough = TerrainState(config, num_envs, seed, config.ctrl_dt, config.episode_length)
        super().__init__(config, num_envs, seed)
        self._stand = float(self.init_qpos[2])
        self._feet = foot_points(self.model, self.init_qpos, self.foot_geoms(self.model))
        self._diverged = np.zeros(num_envs, dtype=bool)
        self.command_ranges(self.rough.command_fraction)
        scan = self.rough.scan_dim
        self.spec = dataclasses.replace(
            self.spec, name=self.NAME, obs_dim=self.spec.obs_dim + (scan if config.perceptive else 0),
            critic_obs_dim=self.spec.critic_obs_dim + scan, episode_metrics=self.rough.metric_names)

    def build_spec(self, config: Any) -> Any:
        spec = super().build_spec(config)
        self.rough.add_to_spec(spec)
        return spec

    def base_states(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        qpos, qvel = super().base_states(idx)
        return self.rough.place(qpos, idx, self._stand, self._feet), qvel

    def extend_obs(self, obs: np.ndarray, critic_obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        obs, critic_obs = super().extend_obs(obs, critic_obs)
        scan = self.rough.scan(self.sim.qpos)
        if self.config.perceptive:
            obs = np.concatenate([obs, scan], axis=1)
        return obs, np.concatenate([critic_obs, scan], axis=1)

    def at_limit(self) -> np.ndarray:
        qpos = self.sim.qpos
        return (super().at_limit() | self.rough.off_map(qpos)
                | out_of_band(qpos[:, 2] - self.base_ground(), self.rough.config.base_height_band))

    def base_ground(self) -> np.ndarray:
        """[M] the ground under each base."""
        return terrain.ground_height(self.rough.sampler, self.sim.qpos[:, 0], self.sim.qpos[:, 1])

    def feet_ground(self, feet: Any) -> np.ndarray:
        """[M, F] the ground under the ``{foot}_pos`` sensors of ``feet``."""
        pos = np.stack([self._s(f"{f}_pos") for f in feet], axis=1)
        return terrain.ground_height(self.rough.sampler, pos[..., 0], pos[..., 1])

    def _after_physics(self, a: np.ndarray, unstable: np.ndarray) -> base.StepOut:
        tracking = go1_math.reward_tracking_lin_vel(self.command, self._s("local_linvel"), self.config.tracking_sigma)
        qpos = self.sim.qpos
        self.rough.record_step(self.command, tracking, self.sim.qvel[:, :2], terrain.yaw_from_quat(qpos[:, 3:7]))
        self._diverged = unstable | ~np.isfinite(qpos).all(axis=1)
        levels = self.rough.levels.copy()  # the ended episodes' levels, before the curriculum moves them
        out = super()._after_physics(a, unstable)
        return out._replace(extras=self.rough.episode_metrics(levels))

    def _reset_and_observe(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.rough.episode_end(idx, self.sim.qpos[idx], self.steps[idx], self._diverged[idx])
        self.command_ranges(self.rough.command_fraction)
        return super()._reset_and_observe(idx)

    def eval_tracker(self, stepper: Any = None) -> TerrainEval:
        """Freezes the task on upper-half levels (call before ``reset``) and returns its evaluation tracker."""
        self.rough.freeze_for_evaluation()
        self.command_ranges(self.rough.command_fraction)
        return TerrainEval(self, stepper)


class TerrainEval:
    """The evaluation tracker of the rough tasks (``step`` / ``result`` / ``LOGGED`` like
    ``walking_metric.WalkingTracker``, over each env's first episode): the walking metric overall and per terrain
    type. ``task`` exposes ``command``, ``base_velocity()`` and ``rough`` (a frozen ``TerrainState``); ``stepper``
    is what ``step`` steps (the task, or a ``_hist`` variant wrapping it)."""

    def __init__(self, task: Any, stepper: Any = None):
        self._task, self._stepper = task, stepper if stepper is not None else task
        m = task.num_envs
        self.active = np.ones(m, dtype=bool)
        self._fell = np.zeros(m, dtype=bool)
        self._sums = np.zeros((m, 2))  # per env: tracking error, yaw-rate error
        self._count = np.zeros(m)
        self.types = tuple(dict.fromkeys(task.rough.terrain.columns))
        self.LOGGED = ("tracking_error", "yaw_rate_error", "fall_rate", "terrain_level", "terrain_level_min",
                       "terrain_level_top", "rough_terrain_walking",
                       *(f"{k}_{t}" for t in self.types for k in ("walking", "tracking_error", "fall_rate")))

    @property
    def done(self) -> bool:
        return not self.active.any()

    def step(self, action: np.ndarray) -> base.StepOut:
        cmd = np.array(self._task.command, dtype=np.float64, copy=True)
        out = self._stepper.step(action)
        ended = out.terminated | out.truncated
        self._fell |= self.active & out.terminated
        ok = self.active & ~ended
        vel = self._task.base_velocity()
        err = np.stack([np.linalg.norm(cmd[:, :2] - vel[:, :2], axis=1), np.abs(cmd[:, 2] - vel[:, 2])], axis=1)
        self._sums += np.where(ok[:, None], err, 0.0)
        self._count += ok
        self.active &= ~ended
        return out

    def result(self) -> dict[str, float]:
        rough = self._task.rough
        return evaluation_numbers(self._sums, self._count, self._fell, rough.levels, rough.cols,
                                  rough.terrain.columns, rough.config.terrain_levels)


def evaluation_numbers(sums: np.ndarray, count: np.ndarray, fell: np.ndarray, levels: np.ndarray, cols: np.ndarray,
                       columns: tuple[str, ...], num_levels: int) -> dict[str, float]:
    """The rough evaluation's numbers (``TerrainEval.LOGGED`` plus ``evaluated_steps`` and ``episodes``) from each
    env's first episode: ``sums [M, 2]`` its tracking and yaw-rate errors summed over ``count [M]`` evaluated steps,
    ``fell [M]`` whether it terminated, on cell (``levels [M]``, ``cols [M]``) of a grid of ``columns`` and
    ``num_levels`` levels. Shared by the CPU tracker and the MJX evaluation (``unilab_jax/training/mjx.py``)."""
    sums, count, fell = np.asarray(sums, np.float64), np.asarray(count, np.float64), np.asarray(fell, bool)
    levels, cols = np.asarray(levels), np.asarray(cols)

    def numbers(envs: np.ndarray) -> dict[str, float]:
        n = count[envs].sum()
        mean = sums[envs].sum(axis=0) / n if n else np.full(2, np.nan)
        return {"tracking_error": float(mean[0]), "yaw_rate_error": float(mean[1]),
                "fall_rate": float(fell[envs].mean())}

    out = {**numbers(np.ones(levels.shape[0], dtype=bool)), "terrain_level": float(levels.mean()),
           "terrain_level_min": float(levels.min()), "terrain_level_top": float(num_levels - 1),
           "evaluated_steps": int(count.sum()), "episodes": int(levels.shape[0])}
    out["rough_terrain_walking"] = float(WALKING.met_on_rough(out))
    names = np.asarray(columns)[cols]
    for t in dict.fromkeys(columns):
        envs = names == t
        if not envs.any():
            out.update({f"walking_{t}": math.nan, f"tracking_error_{t}": math.nan, f"fall_rate_{t}": math.nan})
            continue
        n = numbers(envs)
        out.update({f"walking_{t}": float(WALKING.met(n)), f"tracking_error_{t}": n["tracking_error"],
                    f"fall_rate_{t}": n["fall_rate"]})
    return out
