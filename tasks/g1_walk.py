"""``g1_walk_flat``: Unitree G1 (29 DoF) velocity-tracking walk on flat ground.

The UniLab paper's other headline locomotion task, built like ``go2_joystick_flat`` on the shared walking
machinery (``tasks/walking.py``). The robot is Unitree's own 29-DoF G1 MJCF (``unitree_g1`` through
``mujoco_menagerie``; ``MENAGERIE_ROOT`` for offline copies); joints, bodies and sites are selected by
name, never by Menagerie-only entry points.

* Model (MjSpec edits): sim_dt 0.005, ctrl_dt 0.02 (4 substeps), Euler, Newton solver with at most 10
  iterations / 10 line-search steps, pyramidal cone; the XML's own sensors and the visual/collision
  meshes removed; feet-only contacts: the four 5 mm spheres under each ankle-roll link against the
  floor (the floor has priority, so its friction applies: condim 3); a ``{left,right}_foot`` site at
  the middle of each foot's sphere plane (foot height and velocity); an IMU at the pelvis ``imu`` site.
* Actuation: all 29 motors become PD position servos (``walking.position_servos``: Kp on the actuator,
  Kd as joint damping, torque limits = the motors' own ranges: hips/waist yaw 88, knees 139, ankles and
  waist roll/pitch 50, arms 25, wrist pitch/yaw 5 N m). Gains per joint group, in the range used for
  this robot by Unitree's RL examples: hips kp 100 / kd 2, knees 150 / 4, ankles 40 / 2, waist 200 / 5,
  shoulders, elbows and wrist roll 40 / 1, wrist pitch/yaw 20 / 0.5.
* Policy joints (``policy_joints``): by default the 12 leg joints and the 3 waist joints (15 actions);
  the 14 arm joints are held at their default pose by their servos. Walking needs no arm motion and
  each extra action dimension slows off-policy learning; ``policy_joints="all"`` gives the policy all
  29, ``"legs"`` only the 12 leg joints. ``target = default + 0.5 * clip(action, -1, 1)``.
* Default pose: knees bent (hip pitch -0.312, knee 0.669, ankle pitch -0.363), arms slightly out and
  bent (shoulder pitch 0.2, shoulder roll +-0.2, elbow 0.6); the pelvis at the height where the feet
  touch the floor (~0.76 m).
* Actor observation (58 by default): gyro 3, projected gravity 3, joint pos - default n, joint vel n,
  last action n, command 3, gait phase 4 = (sin, cos) of 2 pi phase of the left then the right foot
  (1.25 Hz clock, offsets 0 / 0.5, stance in [0, 0.5)). Noise U(+-level * scale): gyro 0.1, gravity
  0.05, joint pos 0.01, joint vel 0.2. Critic: the actor observation + clean local linear velocity 3,
  pelvis height 1, foot contacts 2, foot heights 2.
* Reward = 0.02 * sum(scale * term) (not clipped): tracking_lin_vel +1.0 and tracking_ang_vel +0.5
  (exp(-err^2 / 0.25)), lin_vel_z -2, ang_vel_xy -0.05, orientation -2 (|gravity_xy|^2), base_height
  -10 ((z - 0.74)^2), action_rate -0.01, torques -2e-4 (|tau|_2 + |tau|_1, Playground's form),
  feet_contact_phase +0.2 (feet whose contact matches the clock), feet_swing_height +0.5 (swinging
  feet: exp(-(h - 0.08)^2 / 0.0025)), feet_slip -0.1 (|v_xy|^2 of feet on the floor while commanded to
  move), pose -0.5 (weighted L1 from the default: hip roll/yaw and waist 1, ankle roll 0.5, arms 0.5,
  hip pitch / knee / ankle pitch 0.05), termination -20.
* Commands U(vx [-0.5, 1.0], vy [-0.3, 0.3], wz [-0.5, 0.5]), one per episode; episodes of 1000 steps
  (20 s, truncation). Termination: pelvis height < 0.3 m or tilt > 60 degrees.
* Reset: default pose, xy +-0.5 m, yaw +-pi, base velocities U(+-0.3).
* Light domain randomisation (once per env): floor friction U(0.4, 1.0), every body's mass
  x U(0.9, 1.1), torso COM + U(+-0.03) m per axis (``extrinsics``: com_offset 3, floor_friction 1,
  mass_scale 30). No pushes by default (``push_interval_s`` enables them).

Speed: ~4.7-5.2k env steps/s of ``task.step`` (256 envs, uniform random actions with auto-resets, one
single-threaded process pinned to one core, CPU time, on the loaded 2-core dev VM); the 4 substeps of the
29-DoF physics are ~95% of it.
"""

from __future__ import annotations

import dataclasses
import functools

import mujoco
import numpy as np

from tasks import base, walking
from unilab_jax import xp as shim

FEET = ("left", "right")
FOOT_BODIES = ("left_ankle_roll_link", "right_ankle_roll_link")
# Reward terms (in this order) and their default scales; each is the config field ``scale_<term>``.
REWARD_SCALES = {
    "tracking_lin_vel": 1.0, "tracking_ang_vel": 0.5, "lin_vel_z": -2.0, "ang_vel_xy": -0.05, "orientation": -2.0,
    "base_height": -10.0, "action_rate": -0.01, "torques": -2e-4, "feet_contact_phase": 0.2,
    "feet_swing_height": 0.5, "feet_slip": -0.1, "pose": -0.5, "termination": -20.0,
}
REWARD_TERMS = tuple(REWARD_SCALES)
# Default joint angles by joint name (unlisted joints: 0).
DEFAULT_POSE = {
    "left_hip_pitch_joint": -0.312, "right_hip_pitch_joint": -0.312,
    "left_knee_joint": 0.669, "right_knee_joint": 0.669,
    "left_ankle_pitch_joint": -0.363, "right_ankle_pitch_joint": -0.363,
    "left_shoulder_pitch_joint": 0.2, "right_shoulder_pitch_joint": 0.2,
    "left_shoulder_roll_joint": 0.2, "right_shoulder_roll_joint": -0.2,
    "left_elbow_joint": 0.6, "right_elbow_joint": 0.6,
}
POLICY_JOINTS = {"legs": ("hip", "knee", "ankle"), "legs_waist": ("hip", "knee", "ankle", "waist"), "all": ("",)}


def joint_group(name: str) -> str:
    """hip, knee, ankle, waist, wrist (pitch/yaw) or arm (shoulders, elbow, wrist roll), from a joint name."""
    for group in ("hip", "knee", "ankle", "waist"):
        if group in name:
            return group
    return "wrist" if ("wrist_pitch" in name or "wrist_yaw" in name) else "arm"


@dataclasses.dataclass(frozen=True)
class G1Config(walking.WalkingConfig):
    """The G1 model, servo gains and domain randomisation of the G1 tasks, and ``g1_walk_flat``'s walking fields."""

    sim_dt: float = 0.005
    action_scale: float = 0.5
    action_clip: float = 1.0
    policy_joints: str = "legs_waist"  # "legs", "legs_waist" or "all"
    gait_frequency: float = 1.25
    gait_offsets: tuple[float, ...] = (0.0, 0.5)
    noise_gyro: float = 0.1
    noise_gravity: float = 0.05
    noise_joint_pos: float = 0.01
    noise_joint_vel: float = 0.2
    command_low: tuple[float, float, float] = (-0.5, -0.3, -0.5)
    command_high: tuple[float, float, float] = (1.0, 0.3, 0.5)
    reset_base_vel: float = 0.3
    min_base_height: float = 0.3
    tracking_sigma: float = 0.25
    base_height_target: float = 0.74
    swing_height_target: float = 0.08
    swing_height_sigma: float = 0.0025
    push_interval_s: float = 0.0
    push_vel: tuple[float, float, float] = (0.5, 0.5, 0.2)
    # PD gains per joint group (kp N m/rad, kd N m s/rad).
    kp_hip: float = 100.0
    kd_hip: float = 2.0
    kp_knee: float = 150.0
    kd_knee: float = 4.0
    kp_ankle: float = 40.0
    kd_ankle: float = 2.0
    kp_waist: float = 200.0
    kd_waist: float = 5.0
    kp_arm: float = 40.0
    kd_arm: float = 1.0
    kp_wrist: float = 20.0
    kd_wrist: float = 0.5
    # Pose-deviation weights per group (hip pitch, knee and ankle pitch move to walk).
    pose_weight_hip_roll_yaw: float = 1.0
    pose_weight_sagittal: float = 0.05
    pose_weight_ankle_roll: float = 0.5
    pose_weight_waist: float = 1.0
    pose_weight_arm: float = 0.5
    dr_floor_friction: tuple[float, float] = (0.4, 1.0)
    dr_mass_scale: tuple[float, float] = (0.9, 1.1)
    dr_torso_com: float = 0.03
    # > 0: each of the 8 sole contact spheres gets this radius (metres), its centre raised by the difference, so its
    # lowest point (a plane's contact) stays where the model's 5 mm sphere had it; the rough task's 2 cm keep the
    # soles from sinking past their radius into a heightfield (docs/TERRAIN.md)
    sole_radius: float = 0.0


@base.with_reward_scales(REWARD_SCALES)
@dataclasses.dataclass(frozen=True)
class G1WalkConfig(G1Config):
    """Configuration of ``g1_walk_flat`` (override any field by name)."""


def default_config() -> G1WalkConfig:
    return G1WalkConfig()


def build_spec(config: G1Config) -> mujoco.MjSpec:
    """Unitree's G1 scene with the task's MjSpec edits (solver, feet-only contacts, servos, sensors)."""
    spec, feet = walking.robot_spec("unitree_g1", config, lambda spec: [
        g for b in FOOT_BODIES for g in spec.body(b).geoms if g.type == mujoco.mjtGeom.mjGEOM_SPHERE])
    if len(feet) != 8:
        raise ValueError(f"expected 4 contact spheres under each ankle-roll link, found {len(feet)}")
    if config.sole_radius > 0:
        for g in feet:
            lift = config.sole_radius - g.size[0]
            g.size = [config.sole_radius, 0.0, 0.0]
            g.pos = [g.pos[0], g.pos[1], g.pos[2] + lift]
    for s in list(spec.sensors):
        spec.delete(s)
    floor = spec.geom("floor")
    floor.priority, floor.condim = 1, 3
    c = config
    gains = {"hip": (c.kp_hip, c.kd_hip), "knee": (c.kp_knee, c.kd_knee), "ankle": (c.kp_ankle, c.kd_ankle),
             "waist": (c.kp_waist, c.kd_waist), "arm": (c.kp_arm, c.kd_arm), "wrist": (c.kp_wrist, c.kd_wrist)}
    kpkd = [gains[joint_group(a.target)] for a in spec.actuators]
    walking.position_servos(spec, [k for k, _ in kpkd], [d for _, d in kpkd])
    B, S = mujoco.mjtObj.mjOBJ_BODY, mujoco.mjtObj.mjOBJ_SITE
    for f, b in zip(FEET, FOOT_BODIES):
        spheres = np.array([g.pos for g in spec.body(b).geoms if g.type == mujoco.mjtGeom.mjGEOM_SPHERE])
        spec.body(b).add_site(name=f"{f}_foot", pos=spheres.mean(axis=0))
    walking.add_walking_sensors(spec, "imu", [(f, S, f"{f}_foot", B, b) for f, b in zip(FEET, FOOT_BODIES)])
    return spec


def pose_weights(config: G1Config, joint_names) -> np.ndarray:
    c = config

    def weight(name: str) -> float:
        group = joint_group(name)
        if group == "hip":
            return c.pose_weight_sagittal if "pitch" in name else c.pose_weight_hip_roll_yaw
        if group == "knee":
            return c.pose_weight_sagittal
        if group == "ankle":
            return c.pose_weight_ankle_roll if "roll" in name else c.pose_weight_sagittal
        return c.pose_weight_waist if group == "waist" else c.pose_weight_arm

    return np.array([weight(n) for n in joint_names])


# The task's unscaled terms as functions of their inputs (``walking.reward_terms``, tests call it directly).
reward_terms = functools.partial(walking.reward_terms, REWARD_TERMS)


class G1WalkFlat(walking.WalkingTask):
    NAME = "g1_walk_flat"
    REWARD_TERMS = REWARD_TERMS
    FEET = FEET

    def __init__(self, config: G1WalkConfig, num_envs: int, seed: int):
        if config.policy_joints not in POLICY_JOINTS:
            raise ValueError(f"policy_joints {config.policy_joints!r}: choose one of {sorted(POLICY_JOINTS)}")
        super().__init__(config, num_envs, seed)
        names = [self.model.joint(j).name for j in self.model.actuator_trnid[self.policy_idx, 0]]
        self.policy_joint_names = tuple(names)
        self.pose_weight = pose_weights(config, names)

    def build_spec(self, config: G1WalkConfig) -> mujoco.MjSpec:
        return build_spec(config)

    def home_qpos(self, model: mujoco.MjModel) -> np.ndarray:
        qpos = model.qpos0.copy()
        for name, angle in DEFAULT_POSE.items():
            qpos[model.jnt_qposadr[model.joint(name).id]] = angle
        return qpos

    def foot_geoms(self, model: mujoco.MjModel) -> list[int]:
        bodies = {model.body(b).id for b in FOOT_BODIES}
        return [g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies]

    def sole_offsets(self, model: mujoco.MjModel) -> np.ndarray:
        return np.array([model.geom_size[self.foot_geoms(model), 0].max()] * len(FEET))  # sphere radius

    def policy_actuators(self, model: mujoco.MjModel) -> list[int]:
        keys = POLICY_JOINTS[self.config.policy_joints]
        return [i for i in range(model.nu) if any(k in model.joint(model.actuator_trnid[i, 0]).name for k in keys)]

    def critic_extra(self, s):
        xp = shim.namespace(s["base_z"])
        return xp.concat([s["base_z"][:, None], xp.astype(s["contact"], s["base_z"].dtype), s["feet_h"]], axis=1)

    # ---- domain randomisation -----------------------------------------------------------------
    def sample_dr(self) -> dict[str, np.ndarray]:
        c, M, r, nb = self.config, self.num_envs, self._rng, self.model.nbody - 1  # the world has no mass
        if not c.domain_randomization:
            friction = self.model.geom_friction[self.model.geom("floor").id, 0]
            return {"com_offset": np.zeros((M, 3)), "floor_friction": np.full((M, 1), friction),
                    "mass_scale": np.ones((M, nb))}
        return {
            "com_offset": r.uniform(-c.dr_torso_com, c.dr_torso_com, size=(M, 3)),
            "floor_friction": r.uniform(*c.dr_floor_friction, size=(M, 1)),
            "mass_scale": r.uniform(*c.dr_mass_scale, size=(M, nb)),
        }

    def randomize_model(self, model: mujoco.MjModel, i: int) -> None:
        dr = self.dr
        model.geom_friction[model.geom("floor").id, 0] = dr["floor_friction"][i, 0]
        model.body_mass[1:] *= dr["mass_scale"][i]
        model.body_ipos[model.body("torso_link").id] += dr["com_offset"][i]


def make(config: G1WalkConfig, num_envs: int, seed: int) -> G1WalkFlat:
    return G1WalkFlat(config, num_envs, seed)
