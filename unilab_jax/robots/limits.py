"""Safety limits a robot enforces on every step, whatever the policy commands (docs/ROBOTS.md, "Safety limits").

``SafetyLimits``: a workspace box for the tcp position, an orientation cone (the tcp's approach axis within
``cone_deg`` of pointing straight down; the rotation about that axis is free), a per-step joint speed and a
tcp speed, and a contact-force limit. Commands are clamped before they reach the servos (the target pose into
the box shrunk by ``margin`` and into the cone, the joint step to ``max_joint_speed``; a joint target whose
forward kinematics leaves the box or the cone is scaled back towards the measured joints); what is measured
after the step (the tcp more than ``pose_slack`` outside the box or ``cone_slack_deg`` outside the cone, the tcp
speed, a contact force) triggers a protective stop.
``LIMIT_HITS`` names the counters a robot's ``health().limit_hits`` reports.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from unilab_jax.robots import ik

# Commands clamped: workspace (target pose into the box), orientation (into the cone), joint_velocity (joint
# step scaled down), kinematics (a joint target outside the box or cone scaled back). Protective stops: pose
# (measured pose outside the box or cone), tcp_speed, force.
LIMIT_HITS = ("workspace", "orientation", "joint_velocity", "kinematics", "pose", "tcp_speed", "force")
DOWN = np.array([0.0, 0.0, -1.0])
# A joint target passes the kinematic check when its tcp is margin / 2 inside the box and within this many degrees
# beyond the cone (the IK does not reach a commanded orientation exactly).
KINEMATIC_CONE_SLACK_DEG = 5.0


@dataclasses.dataclass(frozen=True)
class SafetyLimits:
    box_low: tuple[float, float, float] = (0.2, -0.45, 0.0)  # tcp position bounds (m, world frame; table: z = 0)
    box_high: tuple[float, float, float] = (0.8, 0.45, 0.45)
    margin: float = 0.005  # commanded tcp targets stay this far inside the box (room for dynamic overshoot)
    cone_deg: float = 60.0  # the tcp approach axis stays within this angle of pointing down
    cone_slack_deg: float = 20.0  # measured tilt beyond cone_deg + this: protective stop
    pose_slack: float = 0.02  # measured tcp farther than this outside the box (a push, a collision): protective stop
    max_joint_speed: float = 2.0  # rad/s of simulated time: the joint targets' change per control period
    max_tcp_speed: float = 1.5  # m/s measured; faster: protective stop (commands move the tcp at most ~0.5 m/s)
    # N, the largest contact force on the arm and gripper; larger: protective stop. The simulated arms' rigid contacts
    # reach ~640 N when random actions jam the peg in its hole: set a physical arm's own rating here.
    max_force: float = 1000.0

    def __post_init__(self):
        lo, hi = np.asarray(self.box_low, float), np.asarray(self.box_high, float)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo) & np.isfinite(hi) & (lo < hi)):
            raise ValueError(f"the workspace box needs 3 finite lows below 3 finite highs, got box_low {self.box_low}, "
                             f"box_high {self.box_high}")
        if not 0.0 <= self.margin < 0.5 * float(np.min(hi - lo)):
            raise ValueError(f"margin must be >= 0 and leave room inside the box {self.box_low}..{self.box_high}, "
                             f"got {self.margin}")
        if not 0.0 <= self.pose_slack < 1.0:
            raise ValueError(f"pose_slack must be in [0, 1) m, got {self.pose_slack}")
        if not 0.0 < self.cone_deg <= 180.0 or not 0.0 <= self.cone_slack_deg <= 90.0:
            raise ValueError(f"cone_deg must be in (0, 180] and cone_slack_deg in [0, 90], got {self.cone_deg}, "
                             f"{self.cone_slack_deg}")
        for name in ("max_joint_speed", "max_tcp_speed", "max_force"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be positive and finite, got {value}")

    def target_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The box commanded targets are clamped into (the workspace shrunk by ``margin``)."""
        return np.asarray(self.box_low) + self.margin, np.asarray(self.box_high) - self.margin

    def violation(self, pos: np.ndarray, quat: np.ndarray, slack: float = 0.0, cone_slack_deg: float = 0.0) -> float:
        """How far the pose (pos [3], quat [4]) is outside the box grown by ``slack`` (shrunk when negative), in
        metres, plus how far its tilt is beyond ``cone_deg + cone_slack_deg``, in radians; 0 inside both."""
        low, high = np.asarray(self.box_low) - slack, np.asarray(self.box_high) + slack
        out = float(np.max(np.maximum(np.maximum(low - pos, pos - high), 0.0)))
        return out + max(0.0, tilt(quat) - math.radians(self.cone_deg + cone_slack_deg))


def tilt(quat: np.ndarray) -> float:
    """Angle (radians) between the approach axis (local z) of the frame ``quat`` [4] and straight down."""
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, dtype=np.float64))
    return float(np.arccos(np.clip(mat.reshape(3, 3)[:, 2] @ DOWN, -1.0, 1.0)))


def clamp_to_cone(quat: np.ndarray, cone: float) -> tuple[np.ndarray, bool]:
    """``quat`` [4] tilted back (the shortest rotation) so its approach axis is within ``cone`` radians of
    straight down; returns (quaternion, whether it was clamped)."""
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, dtype=np.float64))
    z = mat.reshape(3, 3)[:, 2]
    angle = float(np.arccos(np.clip(z @ DOWN, -1.0, 1.0)))
    if angle <= cone:
        return quat, False
    axis = np.cross(z, DOWN)
    norm = float(np.linalg.norm(axis))
    axis = np.array([1.0, 0.0, 0.0]) if norm < 1e-9 else axis / norm  # pointing straight up: tilt about x
    q = ik.quat_mul(ik.quat_from_rotvec(axis * (angle - cone)), quat)
    return q / np.linalg.norm(q), True


def limit_joint_step(q_now: np.ndarray, q_cmd: np.ndarray, max_step: float) -> tuple[np.ndarray, bool]:
    """``q_cmd`` moved towards ``q_now`` (uniformly, keeping the direction) so no joint changes more than
    ``max_step``; returns (joints, whether it was limited)."""
    delta = q_cmd - q_now
    peak = float(np.max(np.abs(delta)))
    if peak <= max_step:
        return q_cmd, False
    return q_now + delta * (max_step / peak), True


def contact_force(model: mujoco.MjModel, data: mujoco.MjData, bodies: np.ndarray) -> float:
    """The largest contact force (N, norm of the force part) on any of ``bodies`` (a bool mask [nbody])."""
    wrench = np.zeros(6)
    peak = 0.0
    for i in range(data.ncon):
        c = data.contact[i]
        if bodies[model.geom_bodyid[c.geom1]] or bodies[model.geom_bodyid[c.geom2]]:
            mujoco.mj_contactForce(model, data, i, wrench)
            peak = max(peak, float(np.linalg.norm(wrench[:3])))
    return peak
