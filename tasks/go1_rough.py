"""``go1_joystick_rough``: ``go1_joystick_flat`` on legged_gym-style rough terrain with its curricula.

The flat task (``tasks/go1_joystick.py``: model, MDP, rewards, domain randomisation) with ``tasks/rough.py``'s
``TerrainState`` plugged into its hooks:

* Model: the flat model with the floor plane replaced by the terrain's heightfield geom (same name and contact
  parameters: foot-contact sensors and floor-friction randomisation read it unchanged).
* Reset: each env starts at its cell's origin (+ the flat task's U(+-reset_xy) jitter and random yaw) with the
  base at the flat standing height (0.278 m) above the highest ground under its feet; at every
  auto-reset the terrain curriculum moves the env's level first (``rough.TerrainState.episode_end``).
* Observation: actor 48 (the flat task's; + the 187 scan values with ``perceptive``); critic 123 + 187: the
  flat critic observation, then the height scan (ground under 17 x 11 points around the base minus the base
  height, clipped to +-1 m).
* Truncation also when a robot comes within 1 m of the map's edge (``off_map``); termination as on flat ground.
* Episode metrics ``terrain_level`` and ``terrain_level_<k>`` (the level histogram); evaluation:
  ``rough.TerrainEval`` (upper-half levels, per-type walking numbers).
* Terrain defaults, scaled to Go1 (about half of ANYmal's leg length, for which legged_gym's ranges are set):
  steps 0.02-0.14 m (legged_gym 0.05-0.23), obstacles 0.02-0.14 m, rough +-0.01-0.06 m, slopes 0-0.4,
  0.25 m treads; 10 levels x 7 types of 8 m cells (legged_gym's size) and a 10 m border: 1000 x 760 samples,
  ~3 MB of heightfield in each env's model copy.
* Command curriculum off by default (``command_curriculum=True`` starts at ``command_start`` of Playground's
  ranges): the flat task learns its full ranges without one.

No MJX variant yet (``tasks/mjx_go1.py`` would need the cell state, the curriculum at reset and the scan in its
jitted step; the math it would run -- ``curriculum``, ``terrain.height_scan`` -- is written on the shim).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from tasks import base, go1_math, rough
from tasks.go1_joystick import Go1JoystickConfig, Go1JoystickFlat, build_spec

NAME = "go1_joystick_rough"


@dataclasses.dataclass(frozen=True)
class Go1RoughConfig(Go1JoystickConfig, rough.RoughConfig):
    """``go1_joystick_flat``'s fields plus the terrain's (``rough.RoughConfig``), with Go1-sized terrain."""

    terrain_rough_height: tuple[float, float] = (0.01, 0.06)
    terrain_step_width: float = 0.25
    terrain_step_height: tuple[float, float] = (0.02, 0.14)
    terrain_obstacle_height: tuple[float, float] = (0.02, 0.14)


def default_config() -> Go1RoughConfig:
    return Go1RoughConfig()


def feet_xy(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """[4, 2] the foot spheres' xy relative to the base in pose ``qpos`` (heading 0), ``go1_math.FEET`` order."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    return np.array([data.geom_xpos[model.geom(f).id, :2] - qpos[:2] for f in go1_math.FEET])


class Go1JoystickRough(Go1JoystickFlat):
    def __init__(self, config: Go1RoughConfig, num_envs: int, seed: int):
        self.rough = rough.TerrainState(config, num_envs, seed, config.ctrl_dt, config.episode_length)
        super().__init__(config, num_envs, seed)
        self._stand = float(self.init_qpos[2])
        self._feet = feet_xy(self.model, self.init_qpos)
        self._cmd_final = self._cmd_a.copy()
        self._cmd_a = self._cmd_final * self.rough.command_fraction
        self._diverged = np.zeros(num_envs, dtype=bool)
        scan = self.rough.scan_dim
        self.spec = dataclasses.replace(
            self.spec, name=NAME, obs_dim=self.spec.obs_dim + (scan if config.perceptive else 0),
            critic_obs_dim=self.spec.critic_obs_dim + scan, episode_metrics=self.rough.metric_names)

    def build_spec(self, config: Go1RoughConfig) -> mujoco.MjSpec:
        spec = build_spec(config)
        self.rough.add_to_spec(spec)
        return spec

    def base_states(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        qpos, qvel = super().base_states(idx)
        return self.rough.place(qpos, idx, self._stand, self._feet), qvel

    def extend_obs(self, obs: np.ndarray, critic_obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        scan = self.rough.scan(self.sim.qpos)
        if self.config.perceptive:
            obs = np.concatenate([obs, scan], axis=1)
        return obs, np.concatenate([critic_obs, scan], axis=1)

    def at_limit(self) -> np.ndarray:
        return super().at_limit() | self.rough.off_map(self.sim.qpos)

    def _after_physics(self, a: np.ndarray, unstable: np.ndarray) -> base.StepOut:
        tracking = go1_math.reward_tracking_lin_vel(self.command, self._s("local_linvel"), self.config.tracking_sigma)
        self.rough.record_step(self.command, tracking)
        self._diverged = unstable | ~np.isfinite(self.sim.qpos).all(axis=1)
        levels = self.rough.levels.copy()  # the ended episodes' levels, before the curriculum moves them
        out = super()._after_physics(a, unstable)
        return out._replace(extras=self.rough.episode_metrics(levels))

    def _reset_and_observe(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.rough.episode_end(idx, self.sim.qpos[idx], self.steps[idx], self._diverged[idx])
        self._cmd_a = self._cmd_final * self.rough.command_fraction
        return super()._reset_and_observe(idx)

    def eval_tracker(self, stepper=None) -> rough.TerrainEval:
        """Freezes the task on upper-half levels (call before ``reset``) and returns its evaluation tracker."""
        self.rough.freeze_for_evaluation()
        self._cmd_a = self._cmd_final.copy()
        return rough.TerrainEval(self, stepper)


def make(config: Go1RoughConfig, num_envs: int, seed: int) -> Go1JoystickRough:
    return Go1JoystickRough(config, num_envs, seed)
