"""``go1_joystick_rough``: ``go1_joystick_flat`` on legged_gym-style rough terrain with its curricula.

The flat task (``tasks/go1_joystick.py``: model, MDP, rewards, domain randomisation) with ``tasks/rough.py``'s
``RoughTask`` (a ``TerrainState`` plugged into its hooks):

* Model: the flat model with the floor plane replaced by the terrain's heightfield geom (same name and contact
  parameters: foot-contact sensors and floor-friction randomisation read it unchanged).
* Reset: each env starts at its cell's origin (+ the flat task's U(+-reset_xy) jitter and random yaw) with the
  base at the flat standing height (0.278 m) above the highest ground under its feet; at every
  auto-reset the terrain curriculum moves the env's level first (``rough.TerrainState.episode_end``).
* Observation: actor 48 (the flat task's; + the 187 scan values with ``perceptive``); critic 123 + 187: the
  flat critic observation, then the height scan (ground under 17 x 11 points around the base minus the base
  height, clipped to +-1 m).
* Rewards: the feet's heights (``feet_clearance``, ``feet_height``) are heights above the ground under each foot.
* Domain randomisation: the flat task's, plus motor strength (each motor's Kp and Kd x U(0.9, 1.1), per env)
  and action latency (the motors get the action of 0 or 1 control steps ago, per env).
* Truncation also when a robot comes within 1 m of the map's edge (``off_map``) or its base leaves ``base_height_band``
  above the ground under it (``rough.out_of_band``); termination as on flat ground.
* Episode metrics ``terrain_level`` and ``terrain_level_<k>`` (the level histogram); evaluation:
  ``rough.TerrainEval`` (upper-half levels, per-type walking numbers).
* Terrain defaults, scaled to Go1 (about half of ANYmal's leg length, for which legged_gym's ranges are set):
  steps 0.02-0.14 m (legged_gym 0.05-0.23), obstacles 0.02-0.14 m, rough +-0.01-0.06 m, slopes 0-0.4,
  0.25 m treads; 10 levels x 7 types of 8 m cells (legged_gym's size) and a 10 m border: 1000 x 760 samples,
  ~3 MB of heightfield in each env's model copy.
* Command curriculum off by default (``command_curriculum=True`` starts at ``command_start`` of Playground's
  ranges): the flat task learns its full ranges without one.

MJX variant: ``tasks/mjx_rough.py`` (``Go1RoughMjx``: this task as the template of ``tasks/mjx_go1.py``'s hooks).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from tasks import go1_math, rough
from tasks.go1_joystick import Go1JoystickConfig, Go1JoystickFlat

NAME = "go1_joystick_rough"


@dataclasses.dataclass(frozen=True)
class Go1RoughConfig(Go1JoystickConfig, rough.SmallQuadrupedRough):
    """``go1_joystick_flat``'s fields plus the terrain's (``rough.RoughConfig``), with Go1-sized terrain."""

    dr_motor_strength: tuple[float, float] = (0.9, 1.1)  # on for rough ground (the flat task's default: off)
    dr_action_delay: tuple[int, int] = (0, 1)


def default_config() -> Go1RoughConfig:
    return Go1RoughConfig()


class Go1JoystickRough(rough.RoughTask, Go1JoystickFlat):
    NAME = NAME

    def foot_geoms(self, model: mujoco.MjModel) -> list[int]:
        return [model.geom(f).id for f in go1_math.FEET]

    def command_ranges(self, fraction: np.ndarray) -> None:
        self._cmd_a = np.array(self.config.command_a) * fraction

    def _sensors(self) -> dict[str, np.ndarray]:
        s = super()._sensors()
        s["feet_z"] = s["feet_z"] - self.feet_ground(go1_math.FEET)  # foot heights above the ground under them
        return s


def make(config: Go1RoughConfig, num_envs: int, seed: int) -> Go1JoystickRough:
    return Go1JoystickRough(config, num_envs, seed)
