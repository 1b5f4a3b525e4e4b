"""``go2_joystick_rough`` and ``g1_walk_rough``: the gait-phase walking tasks on legged_gym-style rough terrain.

``go2_joystick_flat`` / ``g1_walk_flat`` (``tasks/walking.py``: model, MDP, rewards, domain randomisation) with
``tasks/rough.py``'s ``RoughTask`` in their hooks, as ``go1_joystick_rough`` (``tasks/go1_rough.py``):

* Model: the flat model with the floor plane replaced by the terrain's heightfield (same name and contact
  parameters: the contact sensors and the floor-friction randomisation read it unchanged).
* Reset: each env starts at its cell's origin (+ the flat task's jitter and random yaw), the base at the flat
  standing height above the highest ground within ``spawn_radius`` of any of its foot spheres (Go2's 4 foot
  spheres; G1's 8 sole spheres, 4 under each foot, so a foot half on a stair edge stands on it); terrain (and,
  on, command) curriculum at every auto-reset.
* Heights are heights above the ground: the base height (``base_height`` reward, G1's ``min_base_height``
  termination and critic input) above the ground under the base, each foot's height (``feet_swing_height``,
  G1's critic input) above the ground under that foot.
* Observation: the flat task's (+ the 187-value height scan with ``perceptive``); critic: the flat critic
  observation, then the height scan.
* Truncation also within 1 m of the map's edge; episode metrics ``terrain_level`` / ``terrain_level_<k>``;
  ``eval_tracker`` evaluates on the upper-half levels per terrain type (``rough.TerrainEval``).
* Domain randomisation: the flat task's, plus motor strength (each motor's Kp and Kd x U(0.9, 1.1), per env and
  motor) and action latency (the motors get the action of 0 or 1 control steps ago, per env).
* Terrain: Go2 as Go1 (a robot of Go1's size: steps 0.02-0.14 m on 0.25 m treads, obstacles 0.02-0.14 m, rough
  +-0.01-0.06 m, slopes 0-0.4); G1 (legs ~0.7 m) steps 0.02-0.18 m on 0.3 m treads, obstacles 0.02-0.12 m,
  rough +-0.01-0.06 m, slopes 0-0.4. Choices, not tuned.

MJX variants: ``tasks/mjx_rough.py`` (``WalkingRoughMjx``: these tasks as the templates of ``tasks/mjx_walking.py``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from tasks import rough
from tasks.g1_walk import G1WalkConfig, G1WalkFlat
from tasks.go2_joystick import Go2JoystickConfig, Go2JoystickFlat


@dataclasses.dataclass(frozen=True)
class Go2RoughConfig(Go2JoystickConfig, rough.SmallQuadrupedRough):
    """``go2_joystick_flat``'s fields plus the terrain's, with Go2-sized terrain and actuation randomisation."""

    dr_motor_strength: tuple[float, float] = (0.9, 1.1)  # on for rough ground (the flat task's default: off)
    dr_action_delay: tuple[int, int] = (0, 1)
    # one yaw-rate command per episode: circular paths, promoted by the distance made along them (tasks/curriculum.py)
    curriculum_distance: str = "path"


@dataclasses.dataclass(frozen=True)
class G1RoughConfig(G1WalkConfig, rough.RoughConfig):
    """``g1_walk_flat``'s fields plus the terrain's, with G1-sized terrain and actuation randomisation."""

    terrain_rough_height: tuple[float, float] = (0.01, 0.06)
    terrain_step_width: float = 0.3
    terrain_step_height: tuple[float, float] = (0.02, 0.18)
    terrain_obstacle_height: tuple[float, float] = (0.02, 0.12)
    dr_motor_strength: tuple[float, float] = (0.9, 1.1)
    dr_action_delay: tuple[int, int] = (0, 1)
    curriculum_distance: str = "path"  # as Go2's
    sole_radius: float = 0.02  # the 5 mm sole spheres sank past their radius into the heightfield


class WalkingRough(rough.RoughTask):
    """What both walking tasks change on rough ground (before the flat class in the bases)."""

    def command_ranges(self, fraction: np.ndarray) -> None:
        self._cmd_low = np.array(self.config.command_low) * fraction
        self._cmd_high = np.array(self.config.command_high) * fraction

    def _sensors(self) -> dict[str, np.ndarray]:
        s = super()._sensors()
        s["base_z"] = s["base_z"] - self.base_ground()
        s["feet_h"] = s["feet_h"] - self.feet_ground(self.FEET)
        return s


class Go2JoystickRough(WalkingRough, Go2JoystickFlat):
    NAME = "go2_joystick_rough"


class G1WalkRough(WalkingRough, G1WalkFlat):
    NAME = "g1_walk_rough"


def go2_default_config() -> Go2RoughConfig:
    return Go2RoughConfig()


def g1_default_config() -> G1RoughConfig:
    return G1RoughConfig()


def make_go2(config: Go2RoughConfig, num_envs: int, seed: int) -> Go2JoystickRough:
    return Go2JoystickRough(config, num_envs, seed)


def make_g1(config: G1RoughConfig, num_envs: int, seed: int) -> G1WalkRough:
    return G1WalkRough(config, num_envs, seed)
