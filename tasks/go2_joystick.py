"""``go2_joystick_flat``: Unitree Go2 velocity tracking on flat ground, parity with UniLab's go2_joystick_flat.

Follows DESIGN.md's facts about UniLab 1.5.2's task, on the shared walking machinery (``tasks/walking.py``):

* Model: Menagerie's ``unitree_go2`` ``scene.xml`` (``go2.xml``, not the MJX variant) loaded through
  ``mujoco_menagerie`` and edited with ``mujoco.MjSpec``: sim_dt 0.01, ctrl_dt 0.02 (2 substeps), Euler;
  visual meshes stripped; feet-only contacts (the four foot spheres against the floor, nothing else
  collides; condim 3, Menagerie's foot friction/solimp/priority); the 12 torque motors become PD
  position servos ``tau = clip(kp (target - q), +-limit) - kd qdot`` with kp 35, kd 0.5 and the torque
  limits of Menagerie's motor classes: 23.7 N m for the hip (abduction) and thigh joints, 45.43 N m for
  the calf (knee) joints. Menagerie's joint damping (2) is replaced by kd; armature 0.01 and
  frictionloss 0.2 are kept.
* Action: ``target = default pose + 0.4 * action`` with **no clipping** (DESIGN.md; this
  overrides the repo's convention of clipping actions to [-1, 1]: ``action_clip=1.0`` restores it).
  Non-finite actions become 0.
* Actor observation (49): gyro 3, projected gravity 3, joint pos - default 12, joint vel 12, last action
  12 (the action just applied, as UniLab's ``current_actions``; 0 after a reset), command (vx, vy, wz) 3,
  gait phase 4 = (sin, cos) of 2 pi phase of the FL/RR pair, then of the FR/RL pair. The gait clock is
  a 2 Hz trot with per-foot offsets FL 0, FR 0.5, RL 0.5, RR 0 on episode time (phase 0 at reset);
  a foot's stance is phase in [0, 0.5), its swing [0.5, 1). Noise U(+-0.01) on joint pos and U(+-0.1) on
  joint vel (none elsewhere).
* Critic observation (52): the actor observation followed by the clean local linear velocity 3.
* Reward = 0.02 * sum(scale * term), not clipped; ``StepOut.reward_terms`` holds each ``0.02 * scale *
  term``. Terms: tracking_lin_vel +1.0 exp(-|v_xy_cmd - v_xy|^2 / 0.4) (body frame), tracking_ang_vel
  +0.2 exp(-(wz_cmd - gyro_z)^2 / 0.4), lin_vel_z -5 vz^2 (body frame, as UniLab's local linvel),
  ang_vel_xy -0.1 (roll/pitch rate^2 from the gyro), base_height -20 (z - 0.3)^2, action_rate -0.02
  |a - a_prev|^2, pose -0.4 sum |q - q0| (L1), feet_contact_phase +1.5 x the number of feet whose floor
  contact matches the gait clock (touching in stance, lifted in swing), feet_swing_height +4.0 sum over
  swinging feet of exp(-(h - 0.1)^2 / 0.01) with h the foot sphere's lowest point above the floor.
* Commands U(vx [-0.6, 1.0], vy [-0.4, 0.4], wz [-0.8, 0.8]), one per episode. Episode 1000 steps (20 s),
  the time limit is a truncation. Termination: tilt (body z vs world z) > 60 degrees.
* Reset: home keyframe joint pose (0, 0.9, -1.8 per leg) at the height where the feet touch the floor,
  xy +-0.5 m, yaw +-pi, base linear/angular velocities U(+-0.5).
* Domain randomisation (once per env, at construction): kp and kd x U(0.9, 1.1) per joint, base mass
  + U(+-1.5) kg, base COM x + U(+-0.05) m; ``self.dr`` / ``self.extrinsics`` (layout base_com_x 1,
  base_mass_delta 1, kd_scale 12, kp_scale 12). Pushes: every 15 s of episode time the base velocity
  gets + U(+-1, +-1, +-0.5) m/s (world vx, vy, vz).

Speed: ~15-16k env steps/s of ``task.step`` (256 envs, uniform random actions with auto-resets, one
single-threaded process pinned to one core, CPU time, on the loaded 2-core dev VM; physics is ~90% of it).

Choices where DESIGN.md is silent (documented deviations):

* Kd is joint damping (implicit under Euler), so the torque limit clips the P part only -- as UniLab
  applies Kd through ``dof_damping``.
* Solver: Newton with at most 10 iterations / 10 line-search steps (it stops once converged; capped at
  4 or 1 iterations, 0.6% or 6% of uniform random-action steps diverged at this 10 ms step), pyramidal
  cone, impratio 1 (Menagerie's go2.xml: elliptic, impratio 100); feet condim 3 (Menagerie: 6).
* Interpretations: the phase-matched contact term counts every foot whose contact agrees with the clock
  (Unitree RL Gym's "contact" reward), so lifting a swing foot pays as much as planting a stance foot;
  "during swing" in the swing-height term means the clock's swing, not "not touching"; the 4 gait-phase
  observations are sin/cos of the two distinct trot phases.
* A push adds to the base velocity rather than replacing it.
* "Vertical velocity" and "roll/pitch rate" are body frame (IMU velocimeter z, gyro x/y).
* The foot height h is the foot sphere's lowest point; Menagerie's soft foot contacts let a standing
  foot sink ~1 cm, so h is about -0.01 in stance.
* The base starts at the height where the feet touch the floor (~0.29 m); zero action then sags to
  ~0.21 m under kp 35, below the 0.3 m base-height target.
* Unstable envs are truncated and reset with zeroed outputs (``self.unstable_count``); random actions of
  amplitude 3 (targets jumping +-1.2 rad every step): none of 38,400 steps diverged (128 envs x 300 steps;
  ~0.05% did while the joints also had MuJoCo 4's v|v| and v^3 damping at Kd, a bug fixed in
  ``walking.position_servos``).
"""

from __future__ import annotations

import dataclasses
import functools

import mujoco
import numpy as np

from tasks import base, walking

FEET = ("FL", "FR", "RL", "RR")  # Menagerie's foot geoms, in actuator (leg) order
# Reward terms (in this order) and their default scales (UniLab's); each is the config field ``scale_<term>``.
REWARD_SCALES = {
    "tracking_lin_vel": 1.0, "tracking_ang_vel": 0.2, "lin_vel_z": -5.0, "ang_vel_xy": -0.1, "base_height": -20.0,
    "action_rate": -0.02, "pose": -0.4, "feet_contact_phase": 1.5, "feet_swing_height": 4.0,
}
REWARD_TERMS = tuple(REWARD_SCALES)


@base.with_reward_scales(REWARD_SCALES)
@dataclasses.dataclass(frozen=True)
class Go2JoystickConfig(walking.WalkingConfig):
    """Configuration of ``go2_joystick_flat`` (UniLab's values; override any field by name)."""

    kp: float = 35.0
    kd: float = 0.5
    dr_kp_scale: tuple[float, float] = (0.9, 1.1)
    dr_kd_scale: tuple[float, float] = (0.9, 1.1)
    dr_base_mass_delta: float = 1.5
    dr_base_com_x: float = 0.05


def default_config() -> Go2JoystickConfig:
    return Go2JoystickConfig()


def build_spec(config: Go2JoystickConfig) -> mujoco.MjSpec:
    """Menagerie's Go2 scene with the task's MjSpec edits (solver, feet-only contacts, servos, sensors)."""
    spec, _ = walking.robot_spec("unitree_go2", config, lambda spec: [spec.geom(f) for f in FEET])
    n = len(spec.actuators)
    walking.position_servos(spec, [config.kp] * n, [config.kd] * n)
    G = mujoco.mjtObj.mjOBJ_GEOM
    walking.add_walking_sensors(spec, "imu", [(f, G, f, G, f) for f in FEET])
    return spec


# The task's unscaled terms as functions of their inputs (``walking.reward_terms``, tests call it directly).
reward_terms = functools.partial(walking.reward_terms, REWARD_TERMS)


class Go2JoystickFlat(walking.WalkingTask):
    NAME = "go2_joystick_flat"
    REWARD_TERMS = REWARD_TERMS
    FEET = FEET

    def build_spec(self, config: Go2JoystickConfig) -> mujoco.MjSpec:
        return build_spec(config)

    def home_qpos(self, model: mujoco.MjModel) -> np.ndarray:
        return np.array(model.key("home").qpos)

    def foot_geoms(self, model: mujoco.MjModel) -> list[int]:
        return [model.geom(f).id for f in FEET]

    def sole_offsets(self, model: mujoco.MjModel) -> np.ndarray:
        return model.geom_size[self.foot_geoms(model), 0]  # foot sphere radius

    # ---- domain randomisation -----------------------------------------------------------------
    def sample_dr(self) -> dict[str, np.ndarray]:
        c, M, r, nu = self.config, self.num_envs, self._rng, self.model.nu
        if not c.domain_randomization:
            return {"base_com_x": np.zeros((M, 1)), "base_mass_delta": np.zeros((M, 1)),
                    "kd_scale": np.ones((M, nu)), "kp_scale": np.ones((M, nu))}
        return {
            "base_com_x": r.uniform(-c.dr_base_com_x, c.dr_base_com_x, size=(M, 1)),
            "base_mass_delta": r.uniform(-c.dr_base_mass_delta, c.dr_base_mass_delta, size=(M, 1)),
            "kd_scale": r.uniform(*c.dr_kd_scale, size=(M, nu)),
            "kp_scale": r.uniform(*c.dr_kp_scale, size=(M, nu)),
        }

    def randomize_model(self, model: mujoco.MjModel, i: int) -> None:
        c, dr = self.config, self.dr
        kp = c.kp * dr["kp_scale"][i]
        model.actuator_gainprm[:, 0] = kp
        model.actuator_biasprm[:, 1] = -kp
        model.dof_damping[self._act_vadr] = c.kd * dr["kd_scale"][i]
        b = model.body("base").id
        model.body_mass[b] += dr["base_mass_delta"][i, 0]
        model.body_ipos[b, 0] += dr["base_com_x"][i, 0]


def make(config: Go2JoystickConfig, num_envs: int, seed: int) -> Go2JoystickFlat:
    return Go2JoystickFlat(config, num_envs, seed)
