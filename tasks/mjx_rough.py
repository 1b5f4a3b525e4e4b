"""The rough-terrain tasks on MJX: ``go1_joystick_rough``, ``go2_joystick_rough`` and ``g1_walk_rough`` stepped under
``jax.jit``, the CPU tasks' MDP on the accelerator.

Each is its flat MJX task (``tasks/mjx_go1.py``, ``tasks/mjx_walking.py``) with ``RoughMjx`` on its hooks
(``mjx_go1.MjxHooks``), built from a one-env instance of the CPU rough task (the *template*: terrain, cell origins,
scan points, spawn points and the task spec, all from ``tasks/rough.py``'s ``TerrainState``), so both engines run
the same terrain from the same ``terrain_seed`` and the same math (``tasks/terrain.py``, ``tasks/curriculum.py``,
written on the array-API shim):

* Model: the CPU task's (the heightfield geom in place of the floor plane). MJX collides heightfields with spheres
  (``hfield_sphere``: the prisms of a sub-grid around the sphere; up to 4 contacts per foot), capsules and boxes;
  every foot here is a sphere (Go1, Go2: one per foot; G1: four per sole), and nothing else touches the ground.
* State (``extra``, besides the action queue of ``dr_action_delay``): each env's cell (``level``, ``col``), the
  episode's commanded path (``commanded``: its displacement, ``commanded_heading``: its heading;
  ``curriculum.advance_commanded_path``) and its path measure (``walked``, ``asked_path``;
  ``curriculum.advance_walked_path``).
* Reset: new episodes at their cell's origin plus the flat task's jitter, the base at the standing height above the
  highest ground within ``spawn_radius`` of any foot (``terrain.highest_ground``), as ``TerrainState.place``.
* Step: heights above the ground where the CPU task reads them (Go1: foot heights; Go2 / G1: base and foot heights),
  the height scan appended to the critic observation (and, ``perceptive``, the actor's), truncation within 1 m of
  the map's edge, and at every episode end legged_gym's terrain curriculum (``curriculum.next_levels``; envs that
  diverged keep their level) before the auto-reset places the env on its new cell.
* Episode metrics: ``MjxStepOut.extras`` holds ``terrain_level`` and the level histogram ``terrain_level_<k>`` of the
  level each episode was played on (``TaskSpec.episode_metrics``; the MJX trainer logs them as ``episode/...``).
* Evaluation (``freeze_for_evaluation``, before the first reset): env i on column ``i mod columns`` at level
  ``levels // 2 + (i // columns) mod (levels - levels // 2)``, curriculum off, as the CPU task's
  ``freeze_for_evaluation``; ``evaluation_numbers`` gives ``rough.evaluation_numbers`` (per-type walking numbers, the
  rough-terrain criterion).

Not here: the command curriculum (``command_curriculum=True`` is refused: the MJX state has no tracking sums; the
CPU tasks' default is off). Deviations are the flat MJX tasks' (float32, jax random streams, divergence checked
once per control step), plus the heightfield contacts: MJX emits up to 4 contacts per foot from its prism sub-grid,
MuJoCo its own set, so contact forces on uneven ground agree only approximately (``tests/tasks/test_mjx_rough.py``).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from tasks import curriculum, go1_math, go1_rough, rough, terrain, walking_rough
from tasks import mjx_go1 as mg
from tasks.mjx_walking import WalkingMjx

__all__ = ["RoughMjx", "Go1RoughMjx", "WalkingRoughMjx", "make"]


def _f32(x: Any) -> jax.Array:
    return jnp.asarray(np.asarray(x, dtype=np.float32))


class RoughMjx:
    """The rough terrain on an MJX task's hooks (listed before the flat MJX class in the bases). The subclass calls
    ``_init_rough(template)`` at the end of its ``__init__`` with the one-env CPU rough task."""

    def _init_rough(self, template: rough.RoughTask) -> None:
        state = template.rough
        c = self.rough_config = state.config
        if c.command_curriculum:
            raise ValueError("command_curriculum: not in the MJX variants (their state keeps no tracking sums)")
        self.columns, self.num_levels = state.terrain.columns, c.terrain_levels
        self.sampler = {**state.sampler, "heights": _f32(state.sampler["heights"])}
        self.origins, self.points = _f32(state.terrain.origins), _f32(state.points)
        self.feet, self.stand = _f32(template._feet), float(template._stand)
        self.bounds, self.ctrl_dt, self.episode_length = state.bounds, state.ctrl_dt, state.episode_length
        self.spec = template.spec
        self.frozen = False

    def freeze_for_evaluation(self) -> None:
        """Evaluation cells (the module docstring) from the next ``reset`` on, curriculum off."""
        self.frozen = True

    # ---- the hooks --------------------------------------------------------------------------------
    def init_extra(self, key: jax.Array, dr: dict, n: int) -> dict:
        extra = super().init_extra(key, dr, n)
        L, C = self.num_levels, len(self.columns)
        if self.frozen:
            i = jnp.arange(n, dtype=jnp.int32)
            levels, cols = L // 2 + (i // C) % (L - L // 2), i % C
        else:
            rc = self.rough_config
            draws = (jax.random.choice(key, L, (n,), p=jnp.asarray(rough.level_probabilities(rc))).astype(jnp.int32)
                     if rc.init_level_weights else jax.random.randint(key, (n,), 0, rc.max_init_level + 1, jnp.int32))
            levels, cols = curriculum.initial_cells(n, C, draws)
        return {**extra, "level": levels, "col": cols, "commanded": jnp.zeros((n, 2)),
                "commanded_heading": jnp.zeros((n,)), "walked": jnp.zeros((n,)), "asked_path": jnp.zeros((n,))}

    def place(self, qpos: jax.Array, extra: dict) -> jax.Array:
        qpos = qpos.at[:, :2].add(self.origins[extra["level"], extra["col"], :2])
        yaw = terrain.yaw_from_quat(qpos[:, 3:7])[:, None]
        c, s = jnp.cos(yaw), jnp.sin(yaw)
        x = qpos[:, 0:1] + c * self.feet[None, :, 0] - s * self.feet[None, :, 1]
        y = qpos[:, 1:2] + s * self.feet[None, :, 0] + c * self.feet[None, :, 1]
        top = terrain.highest_ground(self.sampler, x.ravel(), y.ravel(), self.rough_config.spawn_radius)
        return qpos.at[:, 2].set(self.stand + top.reshape(x.shape).max(axis=1))

    def extend_obs(self, data: Any, obs: jax.Array, critic_obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        qpos = data.qpos
        scan = terrain.height_scan(self.sampler, qpos[:, :3], terrain.yaw_from_quat(qpos[:, 3:7]), self.points)
        if self.rough_config.perceptive:
            obs = jnp.concatenate([obs, scan], axis=1)
        return obs, jnp.concatenate([critic_obs, scan], axis=1)

    def at_limit(self, data: Any) -> jax.Array:
        x0, x1, y0, y1 = self.bounds
        x, y = data.qpos[:, 0], data.qpos[:, 1]
        band = rough.out_of_band(data.qpos[:, 2] - self.ground(data.qpos), self.rough_config.base_height_band)
        return (x < x0) | (x > x1) | (y < y0) | (y > y1) | band

    def after_transition(self, before: Any, state: Any, out: mg.MjxStepOut, ended: jax.Array,
                         key: jax.Array) -> tuple[Any, mg.MjxStepOut]:
        """The episode metrics of the level each env played on, then (training) the terrain curriculum for the
        ``ended`` envs that did not diverge, as ``TerrainState.episode_end``; the commanded paths restart."""
        state, out = super().after_transition(before, state, out, ended, key)
        c, e = self.rough_config, state.extra
        command = before.info["command"]  # the step's command
        path, heading = curriculum.advance_commanded_path(e["commanded"], e["commanded_heading"], command, self.ctrl_dt)
        qpos = state.data.qpos
        walked, asked_path = curriculum.advance_walked_path(e["walked"], e["asked_path"], state.data.qvel[:, :2],
                                                            terrain.yaw_from_quat(qpos[:, 3:7]), command, self.ctrl_dt)
        levels = e["level"]
        metrics = {"terrain_level": levels.astype(jnp.float32),
                   **{f"terrain_level_{k}": (levels == k).astype(jnp.float32) for k in range(self.num_levels)}}
        if not self.frozen and c.terrain_curriculum:
            if c.curriculum_distance == "path":
                dist, asked = walked, curriculum.per_episode(asked_path, state.steps, self.episode_length)
            else:
                dist = jnp.linalg.norm(qpos[:, :2] - self.origins[levels, e["col"], :2], axis=1)
                asked = curriculum.asked_distance(path, state.steps, self.episode_length)
            moved = curriculum.next_levels(levels, dist, asked, c.terrain_cell_size, self.num_levels,
                                           jax.random.randint(key, levels.shape, 0, self.num_levels, jnp.int32))
            levels = jnp.where(ended & ~mg.diverged(state.data), moved, levels)
        extra = {**e, "level": levels, "commanded": jnp.where(ended[:, None], 0.0, path),
                 "commanded_heading": jnp.where(ended, 0.0, heading), "walked": jnp.where(ended, 0.0, walked),
                 "asked_path": jnp.where(ended, 0.0, asked_path)}
        return state._replace(extra=extra), out._replace(extras=metrics)

    # ---- evaluation ---------------------------------------------------------------------------------
    def evaluation_numbers(self, sums: np.ndarray, count: np.ndarray, fell: np.ndarray, extra: dict) -> dict:
        """``rough.evaluation_numbers`` of an evaluation's per-env sums on the cells of ``extra`` (a state's)."""
        return rough.evaluation_numbers(sums, count, fell, np.asarray(extra["level"]), np.asarray(extra["col"]),
                                        self.columns, self.num_levels)

    def ground(self, pos: jax.Array) -> jax.Array:
        """[...] the ground under world points ``pos [..., >= 2]``."""
        return terrain.ground_height(self.sampler, pos[..., 0], pos[..., 1])


class Go1RoughMjx(RoughMjx, mg.Go1JoystickMjx):
    """``go1_joystick_rough`` on MJX (foot heights above the ground under each foot, as ``Go1JoystickRough``)."""

    def __init__(self, config: go1_rough.Go1RoughConfig, num_envs: int, reset_batch: int = 0):
        self.template = go1_rough.Go1JoystickRough(config, 1, 0)
        self.template.close()
        super().__init__(config, num_envs, reset_batch)
        self._init_rough(self.template)

    def model_spec(self) -> mujoco.MjSpec:
        return self.template.build_spec(self.config)

    def _sensors(self, data: Any) -> dict:
        s = super()._sensors(data)
        feet = jnp.stack([data.sensordata[:, self.sensor_index[f"{f}_pos"][0] : self.sensor_index[f"{f}_pos"][0] + 2]
                          for f in go1_math.FEET], axis=1)
        return {**s, "feet_z": s["feet_z"] - self.ground(feet)}


class WalkingRoughMjx(RoughMjx, WalkingMjx):
    """``go2_joystick_rough`` / ``g1_walk_rough`` on MJX (base and foot heights above the ground under them, as
    ``walking_rough.WalkingRough``)."""

    def __init__(self, task_cls: type[walking_rough.WalkingRough], config: Any, num_envs: int, reset_batch: int = 0):
        super().__init__(task_cls, config, num_envs, reset_batch)
        self._init_rough(self.template)

    def sensors(self, data: Any, info: dict, steps: jax.Array) -> dict:
        s = super().sensors(data, info, steps)
        sd, index = self.cpu_sensordata(data.sensordata), self.layout["index"]
        feet = jnp.stack([sd[:, index[f"{f}_pos"][0] : index[f"{f}_pos"][0] + 2] for f in self.template.FEET], axis=1)
        return {**s, "base_z": s["base_z"] - self.ground(data.qpos), "feet_h": s["feet_h"] - self.ground(feet)}


_TASKS = {go1_rough.Go1RoughConfig: (Go1RoughMjx, None),
          walking_rough.Go2RoughConfig: (WalkingRoughMjx, walking_rough.Go2JoystickRough),
          walking_rough.G1RoughConfig: (WalkingRoughMjx, walking_rough.G1WalkRough)}


def make(config: Any, num_envs: int, reset_batch: int = 0, evaluation: bool = False) -> RoughMjx:
    """The MJX env of the rough task whose config ``config`` is; ``evaluation``: frozen on the evaluation cells."""
    if type(config) not in _TASKS:
        raise ValueError(f"no MJX rough task for config {type(config).__name__}")
    cls, task_cls = _TASKS[type(config)]
    env = cls(config, num_envs, reset_batch) if task_cls is None else cls(task_cls, config, num_envs, reset_batch)
    if evaluation:
        env.freeze_for_evaluation()
    return env
