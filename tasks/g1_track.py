"""``g1_track``: Unitree G1 (29 DoF) whole-body motion tracking of the reference clips of ``tasks/g1_motions.py``.

Built on ``g1_walk_flat`` (``tasks/g1_walk.py``): the same model (Unitree's MJCF with the walk's MjSpec edits:
solver, feet-only contacts, PD position servos with the same gains, IMU and foot sensors), the same light
domain randomisation (floor friction, link masses, torso COM) and the shared ``WalkingTask`` machinery
(``BatchedSim`` physics, observation noise, instability handling, auto-reset). What differs:

* Reference: the clips of ``clip_dir`` (default: the committed ``tasks/motions/*.npz``), 50 fps = the control
  rate. Each env follows one clip at a time; when a clip ends the env goes on with a random clip from its
  first frame, placed at the robot's pelvis xy and heading at that moment (every clip starts and
  ends in the standing pose), so episodes are ``episode_length`` steps whatever the clips' lengths.
* Actions: all 29 joints (``policy_joints="all"``); servo target = the reference's joint angles at the next
  frame + ``scale_j * clip(action, -1, 1)`` (a residual on the reference: a zero action replays the clip
  through the servos), ``scale_j`` = 0.5 x the joint's torque limit / its kp (0.125 rad for the wrists and
  waist roll/pitch up to 0.62 for the ankles): light joints get small residuals, so exploration noise does
  not shake the wrists.
* Tracked bodies (``g1_motions.TRACKED_BODIES``, 14, as BeyondMimic tracks): world pose and velocity from
  frame sensors. The anchor body (``torso_link``) is tracked in the world; the other bodies relative to it:
  each reference body is moved rigidly, by the heading difference about the vertical and the anchor's
  horizontal offset, onto the robot's anchor (``anchor_relative_targets``), so drift of the whole body
  costs only in the anchor terms.
* Reward = ctrl_dt * sum(scale * term) (not clipped), terms (``tracking_terms``; exp(-err / sigma)):
  anchor_pos 0.5 (squared position error, sigma 0.09 m^2), anchor_ori 0.5 (squared rotation angle, sigma
  0.16 rad^2), body_pos 1.0 (mean over bodies of the squared position error, 0.09), body_ori 1.0 (mean
  squared angle, 0.16), body_lin_vel 1.0 (mean squared linear-velocity error, 1.0 (m/s)^2), body_ang_vel
  1.0 (mean squared angular-velocity error, 9.87 (rad/s)^2); action_rate -0.1 (|a - a_prev|^2);
  joint_limit -10 (radians beyond the soft joint range, 90% of the limits). Weights and sigmas follow
  BeyondMimic (Liao et al. 2025).
* Termination: anchor height error > 0.25 m, |projected-gravity z of the robot's anchor - the reference's|
  > 0.8, or the height error of an end effector (ankle-roll and wrist-yaw links) > 0.25 m.
* Reset: reference state initialisation at a sampled clip frame (``rsi_*`` noise on the root pose and
  velocity and the joints). Starts are sampled per clip bin of ``bin_seconds`` (``bin_probabilities``):
  p = uniform / N + (1 - uniform) * s / sum(s), with s the failure counts (decayed by ``failure_decay`` each
  step) spread to the ``spread_bins`` - 1 bins before each failure with weights ``spread_decay^k``; a bin
  where episodes fail is drawn more often. Each worker keeps its own counts.
* Actor observation (161): gyro 3, projected gravity 3, joint pos - default 29, joint vel 29, last action
  29 (the walk's layout and noise), then the reference: joint angles - default at each of
  ``reference_frames`` ahead (29 each, (1, 4) by default), the reference anchor's position in the robot
  anchor's frame 3 and its orientation relative to the robot anchor's (two rotation-matrix columns) 6 at the
  next frame, and the clip phase (frame / last frame) 1. Critic: the actor observation without noise +
  local linear velocity 3, pelvis height 1, foot contacts 2, the robot's tracked bodies in its anchor frame
  42 and their errors to the anchor-relative targets in that frame 42.
* Evaluation (``eval_tracker``): env i plays clip i mod n from its first frame without start noise; the
  metric is the fraction of these clips completed without termination and the mean per-body position
  error (m, world frame) over them.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping

import mujoco
import numpy as np

from tasks import base, g1_motions, g1_walk, go1_math, walking
from tasks.floating_base import gravity_from_quat, quat_mul
from unilab_jax import xp as shim

REWARD_SCALES = {"anchor_pos": 0.5, "anchor_ori": 0.5, "body_pos": 1.0, "body_ori": 1.0, "body_lin_vel": 1.0,
                 "body_ang_vel": 1.0, "action_rate": -0.1, "joint_limit": -10.0}
REWARD_TERMS = tuple(REWARD_SCALES)
END_EFFECTORS = ("left_ankle_roll_link", "right_ankle_roll_link", "left_wrist_yaw_link", "right_wrist_yaw_link")


@base.with_reward_scales(REWARD_SCALES)
@dataclasses.dataclass(frozen=True)
class G1TrackConfig(g1_walk.G1Config):
    """Configuration of ``g1_track`` (the G1 model, gains and randomisation fields come from ``G1Config``; its
    command, gait and walking-reward fields are unused)."""

    episode_length: int = 500
    policy_joints: str = "all"
    # Residual scale per joint = action_torque_fraction x torque limit / kp (BeyondMimic's rule, there with 0.25):
    # hips 0.44, knees 0.46, ankles 0.62, waist yaw 0.22, waist roll/pitch 0.125, arms 0.31, wrist pitch/yaw
    # 0.125 rad; 0: ``action_scale`` for every joint.
    action_torque_fraction: float = 0.5
    clip_dir: str = g1_motions.CLIP_DIR
    reference_frames: tuple[int, ...] = (1, 4)  # frames ahead whose joint angles the actor sees
    sigma_anchor_pos: float = 0.09
    sigma_anchor_ori: float = 0.16
    sigma_body_pos: float = 0.09
    sigma_body_ori: float = 0.16
    sigma_body_lin_vel: float = 1.0
    sigma_body_ang_vel: float = 9.87
    soft_limit_fraction: float = 0.9
    max_anchor_height_error: float = 0.25
    max_anchor_gravity_error: float = 0.8
    max_end_effector_height_error: float = 0.25
    # Reference state initialisation noise: root xy (m), root yaw (rad), joints (rad), root velocities.
    rsi_xy: float = 0.05
    rsi_yaw: float = 0.1
    rsi_joint: float = 0.05
    rsi_vel: float = 0.1
    # Adaptive start sampling.
    bin_seconds: float = 0.5
    sampling_uniform: float = 0.1
    spread_bins: int = 3
    spread_decay: float = 0.8
    failure_decay: float = 0.999


def default_config() -> G1TrackConfig:
    return G1TrackConfig()


def build_spec(config: G1TrackConfig) -> mujoco.MjSpec:
    """``g1_walk_flat``'s model plus world-frame pose and velocity sensors on each tracked body's frame."""
    spec = g1_walk.build_spec(config)
    S, X = mujoco.mjtSensor, mujoco.mjtObj.mjOBJ_XBODY
    for b in g1_motions.TRACKED_BODIES:
        for suffix, kind in (("pos", S.mjSENS_FRAMEPOS), ("quat", S.mjSENS_FRAMEQUAT),
                             ("linvel", S.mjSENS_FRAMELINVEL), ("angvel", S.mjSENS_FRAMEANGVEL)):
            spec.add_sensor(name=f"track_{b}_{suffix}", type=kind, objtype=X, objname=b)
    return spec


# --------------------------------------------------------------------------------------------------
# Task math on the shim: [..., 4] quaternions (w, x, y, z), [..., 3] vectors; M envs, B bodies.
# --------------------------------------------------------------------------------------------------
def quat_conj(q):
    xp = shim.namespace(q)
    return xp.concat([q[..., :1], -q[..., 1:]], axis=-1)


def _cross(a, b):
    """Cross product over the last axis, written out (numpy's ``cross`` moves axes around: 1.5x slower here)."""
    xp = shim.namespace(a, b)
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return xp.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def quat_rotate(q, v):
    """R(q) v."""
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * _cross(u, v)
    return v + w * t + _cross(u, t)


def quat_angle(a, b):
    """Rotation angle (rad, in [0, pi]) between orientations ``a`` and ``b``."""
    xp = shim.namespace(a, b)
    d = quat_mul(quat_conj(a), b)
    return 2.0 * xp.atan2(xp.sqrt(xp.sum(xp.square(d[..., 1:]), axis=-1)), xp.abs(d[..., 0]))


def heading(q):
    """Yaw (rad) of the body x axis about the world vertical."""
    xp = shim.namespace(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return xp.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def yaw_quat(yaw):
    xp = shim.namespace(yaw)
    zero = xp.zeros_like(yaw)
    return xp.stack([xp.cos(yaw / 2), zero, zero, xp.sin(yaw / 2)], axis=-1)


def anchor_relative_targets(anchor_pos, anchor_quat, ref_anchor_pos, ref_anchor_quat, ref_pos, ref_quat, ref_lin,
                            ref_ang):
    """The reference bodies moved rigidly onto the robot's anchor: rotated by the heading difference
    (robot anchor - reference anchor) about the vertical and placed so the reference anchor lands at the
    robot anchor's xy and the reference anchor's height. Anchors [M, 3] / [M, 4]; bodies [M, B, 3|4].
    Returns (pos, quat, lin_vel, ang_vel) targets, world frame."""
    xp = shim.namespace(anchor_pos, ref_pos)
    dq = yaw_quat(heading(anchor_quat) - heading(ref_anchor_quat))[:, None, :]
    base = xp.concat([anchor_pos[:, :2], ref_anchor_pos[:, 2:3]], axis=-1)[:, None, :]
    pos = base + quat_rotate(dq, ref_pos - ref_anchor_pos[:, None, :])
    return pos, quat_mul(dq, ref_quat), quat_rotate(dq, ref_lin), quat_rotate(dq, ref_ang)


def tracking_terms(*, anchor, body_pos, body_quat, body_lin, body_ang, ref_anchor_pos, ref_anchor_quat, target_pos,
                   target_quat, target_lin, target_ang, action, last_act, joint_pos, soft_lower, soft_upper,
                   sigmas: Mapping[str, float]):
    """Unscaled terms {name: [M]} in ``REWARD_TERMS`` order. ``anchor``: index of the anchor among the B
    bodies; body_* [M, B, .] the robot's (world frame); target_* the ``anchor_relative_targets``;
    ``sigmas``: {term: sigma} of the six exp(-err / sigma) tracking terms."""
    xp = shim.namespace(body_pos)

    def k(name, err):
        return xp.exp(-err / sigmas[name])

    def sq(x):
        return xp.sum(xp.square(x), axis=-1)

    return {
        "anchor_pos": k("anchor_pos", sq(body_pos[:, anchor] - ref_anchor_pos)),
        "anchor_ori": k("anchor_ori", xp.square(quat_angle(body_quat[:, anchor], ref_anchor_quat))),
        "body_pos": k("body_pos", xp.mean(sq(body_pos - target_pos), axis=-1)),
        "body_ori": k("body_ori", xp.mean(xp.square(quat_angle(body_quat, target_quat)), axis=-1)),
        "body_lin_vel": k("body_lin_vel", xp.mean(sq(body_lin - target_lin), axis=-1)),
        "body_ang_vel": k("body_ang_vel", xp.mean(sq(body_ang - target_ang), axis=-1)),
        "action_rate": go1_math.cost_action_rate(action, last_act),
        "joint_limit": go1_math.cost_dof_pos_limits(joint_pos, soft_lower, soft_upper),
    }


def tracking_terminated(anchor_pos, anchor_quat, ref_anchor_pos, ref_anchor_quat, ee_z, ref_ee_z,
                        max_height_error: float, max_gravity_error: float, max_ee_error: float):
    """[M] bool: anchor height error, anchor projected-gravity z error or any end-effector height error
    (``ee_z`` / ``ref_ee_z`` [M, E]) beyond its threshold."""
    xp = shim.namespace(anchor_pos)
    gz = gravity_from_quat(anchor_quat)[:, 2]
    ref_gz = gravity_from_quat(ref_anchor_quat)[:, 2]
    return ((xp.abs(anchor_pos[:, 2] - ref_anchor_pos[:, 2]) > max_height_error)
            | (xp.abs(gz - ref_gz) > max_gravity_error)
            | xp.any(xp.abs(ee_z - ref_ee_z) > max_ee_error, axis=-1))


def bin_probabilities(failures, bin_clip, uniform: float, spread_bins: int, spread_decay: float):
    """Start probabilities [N] of the N clip bins (bins in clip order, ``bin_clip [N]`` their clip).

    s[b] = sum_{k < spread_bins, bin b+k in b's clip} spread_decay^k * failures[b + k];
    p = uniform / N + (1 - uniform) * s / sum(s), or 1 / N while no bin has failed."""
    xp = shim.namespace(failures)
    n = failures.shape[0]
    s = xp.zeros_like(failures)
    for k in range(spread_bins):
        same = xp.astype(bin_clip[k:] == bin_clip[: n - k], failures.dtype)
        s = s + xp.concat([(spread_decay**k) * failures[k:] * same, xp.zeros_like(failures[:k])])
    total = xp.sum(s)
    if float(total) <= 0.0:
        return xp.full((n,), 1.0 / n, dtype=failures.dtype)
    return uniform / n + (1.0 - uniform) * s / total


def rotation_6d(q):
    """The first two columns of R(q), [M, 6] (a continuous orientation feature)."""
    xp = shim.namespace(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return xp.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y),
                     2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)], axis=-1)


# --------------------------------------------------------------------------------------------------
# The numpy task
# --------------------------------------------------------------------------------------------------
def _rotate_xy(yaw: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """[n, 2] ``xy`` rotated by ``yaw`` [n] about the vertical."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]], axis=1)


class Clips:
    """The clips of a folder concatenated: frame g of the whole set is frame g - start[c] of clip c."""

    def __init__(self, paths: list[str], joint_names: tuple[str, ...], ctrl_dt: float):
        if not paths:
            raise ValueError("no clips: the clip folder holds no .npz files")
        clips = [g1_motions.load_clip(p) for p in paths]
        for p, c in zip(paths, clips):
            if abs(float(c["fps"]) * ctrl_dt - 1.0) > 1e-6:
                raise ValueError(f"{p}: {float(c['fps'])} fps, but the task steps at {1 / ctrl_dt:g} Hz")
            if tuple(c["joint_names"]) != joint_names:
                raise ValueError(f"{p}: its joints {tuple(c['joint_names'])} are not the model's {joint_names}")
            if tuple(c["body_names"]) != tuple(clips[0]["body_names"]) or str(c["anchor_body"]) != str(
                    clips[0]["anchor_body"]):
                raise ValueError(f"{p}: tracks other bodies than {paths[0]}")
        self.names = tuple(os.path.basename(p).removesuffix(".npz") for p in paths)
        self.body_names = tuple(str(b) for b in clips[0]["body_names"])
        self.anchor = self.body_names.index(str(clips[0]["anchor_body"]))
        self.length = np.array([c["qpos"].shape[0] for c in clips])
        self.start = np.concatenate([[0], np.cumsum(self.length)[:-1]])
        for k in ("qpos", "qvel", "body_pos", "body_quat", "body_lin_vel", "body_ang_vel"):
            setattr(self, k, np.concatenate([c[k] for c in clips]).astype(np.float64))

    def index(self, clip: np.ndarray, frame: np.ndarray) -> np.ndarray:
        """Global frame indices of (clip, frame), frames clamped to the clip."""
        return self.start[clip] + np.clip(frame, 0, self.length[clip] - 1)


class G1Track(g1_walk.G1WalkFlat):
    NAME = "g1_track"
    REWARD_TERMS = REWARD_TERMS

    def __init__(self, config: G1TrackConfig, num_envs: int, seed: int):
        if not config.reference_frames or min(config.reference_frames) < 1:
            raise ValueError(f"reference_frames must be frames ahead (>= 1), got {config.reference_frames}")
        if config.bin_seconds <= 0 or not 0.0 <= config.sampling_uniform <= 1.0 or config.spread_bins < 1:
            raise ValueError("bin_seconds > 0, sampling_uniform in [0, 1] and spread_bins >= 1 are required")
        super().__init__(config, num_envs, seed)
        m, M, c = self.model, self.num_envs, config
        joints = tuple(m.joint(j).name for j in range(1, m.njnt))
        self.clips = Clips(g1_motions.clip_paths(c.clip_dir), joints, c.ctrl_dt)
        cl = self.clips
        self._ee = np.array([cl.body_names.index(b) for b in END_EFFECTORS])
        self._track_adr = {k: np.array([self._sensor[f"track_{b}_{k}"][0] for b in cl.body_names])
                           for k in ("pos", "quat", "linvel", "angvel")}
        jnt = m.actuator_trnid[self.policy_idx, 0]
        lo, hi = m.jnt_range[jnt, 0], m.jnt_range[jnt, 1]
        mid, half = (lo + hi) / 2, (hi - lo) / 2 * c.soft_limit_fraction
        self.soft_lower, self.soft_upper = mid - half, mid + half
        self.sigmas = {k: getattr(c, f"sigma_{k}") for k in REWARD_TERMS[:6]}
        act = self.policy_idx
        self.action_scales = (c.action_torque_fraction * m.actuator_forcerange[act, 1] / m.actuator_gainprm[act, 0]
                              if c.action_torque_fraction > 0 else np.full(act.size, c.action_scale))
        # Clip bins for the start sampling.
        bin_frames = max(1, round(c.bin_seconds / c.ctrl_dt))
        nbins = -(-cl.length // bin_frames)
        self.bin_clip = np.repeat(np.arange(len(cl.length)), nbins)
        self.bin_first = np.concatenate([np.arange(n) * bin_frames for n in nbins])
        self.bin_last = np.minimum(self.bin_first + bin_frames, cl.length[self.bin_clip]) - 1
        self.bin_offset = np.concatenate([[0], np.cumsum(nbins)[:-1]])
        self.bin_frames = bin_frames
        self.failures = np.zeros(self.bin_clip.size)
        # Per-env reference state: clip, frame, and the clip's placement (xy offset, heading) in the world.
        self.clip = np.zeros(M, dtype=np.int64)
        self.frame = np.zeros(M, dtype=np.int64)
        self.origin_xy = np.zeros((M, 2))
        self.origin_yaw = np.zeros(M)
        self.clip_finished = np.zeros(M, dtype=bool)  # the env reached its clip's last frame this step
        self.body_pos_error = np.zeros(M)  # mean world-frame distance to the reference bodies this step
        self.play_from_start = False  # evaluation: env i plays clip i mod n from frame 0, no start noise
        obs, cobs = self._observe(self._state())
        self.spec = dataclasses.replace(self.spec, obs_dim=obs.shape[1], critic_obs_dim=cobs.shape[1])

    def build_spec(self, config: G1TrackConfig) -> mujoco.MjSpec:
        return build_spec(config)

    # ---- reference ------------------------------------------------------------------------------
    def _place(self, g: np.ndarray, env: np.ndarray):
        """Reference bodies at global frames ``g`` in the world placement of envs ``env``: (pos, quat,
        lin_vel, ang_vel) [len, B, .]."""
        cl = self.clips
        q = yaw_quat(self.origin_yaw[env])[:, None, :]
        off = np.concatenate([self.origin_xy[env], np.zeros((env.size, 1))], axis=1)[:, None, :]
        return (off + quat_rotate(q, cl.body_pos[g]), quat_mul(q, cl.body_quat[g]),
                quat_rotate(q, cl.body_lin_vel[g]), quat_rotate(q, cl.body_ang_vel[g]))

    def _root_in_world(self, g: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(xy [n, 2], heading [n]) of the reference pelvis at frames ``g`` placed for envs ``env``."""
        yaw = self.origin_yaw[env]
        return self.origin_xy[env] + _rotate_xy(yaw, self.clips.qpos[g, :2]), yaw + heading(self.clips.qpos[g, 3:7])

    def _start_clip(self, env: np.ndarray, clip: np.ndarray, frame: np.ndarray, xy: np.ndarray, yaw: np.ndarray):
        """Envs ``env`` follow ``clip`` from ``frame``, placed so that frame's pelvis is at ``xy`` / ``yaw``."""
        g = self.clips.index(clip, frame)
        self.clip[env], self.frame[env] = clip, frame
        self.origin_yaw[env] = yaw - heading(self.clips.qpos[g, 3:7])
        self.origin_xy[env] = xy - _rotate_xy(self.origin_yaw[env], self.clips.qpos[g, :2])

    # ---- hooks ----------------------------------------------------------------------------------
    def _state(self) -> dict:
        """Sensors, robot bodies and the reference at the current frame (world frame, [M, B, .])."""
        s = walking.read_sensors(self.sim.sensordata, self.sim.qpos, self.sim.qvel, self.sensor_layout())
        sd = self.sim.sensordata
        for key, name, dim in (("pos", "body_pos", 3), ("quat", "body_quat", 4), ("linvel", "body_lin", 3),
                               ("angvel", "body_ang", 3)):
            s[name] = sd[:, self._track_adr[key][:, None] + np.arange(dim)]
        env = np.arange(self.num_envs)
        ref = self._place(self.clips.index(self.clip, self.frame), env)
        s["ref_pos"], s["ref_quat"], s["ref_lin"], s["ref_ang"] = ref
        return s

    def _observe(self, s: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        cl, a, M = self.clips, self.clips.anchor, self.num_envs
        env = np.arange(M)
        refs = [cl.qpos[cl.index(self.clip, self.frame + k)][:, self._act_qadr[self.policy_idx]] - self.default_pose
                for k in self.config.reference_frames]
        nxt_pos, nxt_quat, _, _ = self._place(cl.index(self.clip, self.frame + 1), env)
        apos, aquat = s["body_pos"][:, a], s["body_quat"][:, a]
        inv = quat_conj(aquat)
        reference = np.concatenate(refs + [quat_rotate(inv, nxt_pos[:, a] - apos),
                                           rotation_6d(quat_mul(inv, nxt_quat[:, a]))], axis=1)
        phase = (self.frame / (cl.length[self.clip] - 1))[:, None]
        args = (s["gyro"], s["gravity"], s["joint_pos"], s["joint_vel"], self.last_act, reference, phase,
                self.default_pose)
        obs = walking.actor_obs(*args, self._noise())
        clean = walking.actor_obs(*args, np.zeros((M, self._noise_scale.size)))
        target, _, _, _ = anchor_relative_targets(apos, aquat, s["ref_pos"][:, a], s["ref_quat"][:, a],
                                                  s["ref_pos"], s["ref_quat"], s["ref_lin"], s["ref_ang"])
        local = quat_rotate(inv[:, None, :], s["body_pos"] - apos[:, None, :]).reshape(M, -1)
        err = quat_rotate(inv[:, None, :], target - s["body_pos"]).reshape(M, -1)
        cobs = np.concatenate([clean, s["local_linvel"], s["base_z"][:, None], s["contact"].astype(np.float64),
                               local, err], axis=1)
        return obs, cobs

    def _ctrl(self, action: np.ndarray) -> np.ndarray:
        ctrl = self.clips.qpos[self.clips.index(self.clip, self.frame + 1)][:, self._act_qadr]
        ctrl[:, self.policy_idx] += self.action_scales * action
        return ctrl

    def start_probabilities(self) -> np.ndarray:
        c = self.config
        return bin_probabilities(self.failures, self.bin_clip, c.sampling_uniform, c.spread_bins, c.spread_decay)

    def _reset_envs(self, idx: np.ndarray) -> None:
        c, r, n, cl = self.config, self._rng, idx.size, self.clips
        if self.play_from_start:
            clip, frame = idx % len(cl.length), np.zeros(n, dtype=np.int64)
        else:
            b = r.choice(self.bin_clip.size, size=n, p=self.start_probabilities())
            clip, frame = self.bin_clip[b], r.integers(self.bin_first[b], self.bin_last[b] + 1)
        g = cl.index(clip, frame)
        self.origin_xy[idx], self.origin_yaw[idx] = 0.0, 0.0
        qpos, qvel = cl.qpos[g].copy(), cl.qvel[g].copy()
        if not self.play_from_start:
            qpos[:, :2] += r.uniform(-c.rsi_xy, c.rsi_xy, size=(n, 2))
            qpos[:, 3:7] = quat_mul(yaw_quat(r.uniform(-c.rsi_yaw, c.rsi_yaw, size=n)), qpos[:, 3:7])
            qpos[:, 7:] += r.uniform(-c.rsi_joint, c.rsi_joint, size=(n, qpos.shape[1] - 7))
            qvel[:, :6] += r.uniform(-c.rsi_vel, c.rsi_vel, size=(n, 6))
        jnt = np.arange(1, self.model.njnt)
        qpos[:, 7:] = np.clip(qpos[:, 7:], self.model.jnt_range[jnt, 0], self.model.jnt_range[jnt, 1])
        self.clip[idx], self.frame[idx] = clip, frame
        self.sim.set_state(idx, qpos, qvel, ctrl=cl.qpos[cl.index(clip, frame)][:, self._act_qadr])
        self.last_act[idx] = 0.0
        self.steps[idx] = 0

    def _reset_and_observe(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._reset_envs(idx)
        return self._observe(self._state())

    def _after_physics(self, a: np.ndarray, unstable: np.ndarray) -> base.StepOut:
        c, cl = self.config, self.clips
        self.steps += 1
        self.frame += 1
        s = self._state()
        anc = cl.anchor
        apos, aquat = s["body_pos"][:, anc], s["body_quat"][:, anc]
        rpos, rquat = s["ref_pos"][:, anc], s["ref_quat"][:, anc]
        target = anchor_relative_targets(apos, aquat, rpos, rquat, s["ref_pos"], s["ref_quat"], s["ref_lin"],
                                         s["ref_ang"])
        terms = tracking_terms(anchor=anc, body_pos=s["body_pos"], body_quat=s["body_quat"], body_lin=s["body_lin"],
                               body_ang=s["body_ang"], ref_anchor_pos=rpos, ref_anchor_quat=rquat,
                               target_pos=target[0], target_quat=target[1], target_lin=target[2],
                               target_ang=target[3], action=a, last_act=self.last_act, joint_pos=s["joint_pos"],
                               soft_lower=self.soft_lower, soft_upper=self.soft_upper, sigmas=self.sigmas)
        done = tracking_terminated(apos, aquat, rpos, rquat, s["body_pos"][:, self._ee, 2],
                                   s["ref_pos"][:, self._ee, 2], c.max_anchor_height_error,
                                   c.max_anchor_gravity_error, c.max_end_effector_height_error)
        scaled = go1_math.scale_terms(terms, self.scales, self.dt)
        reward = np.sum(np.stack(list(scaled.values())), axis=0)
        self.body_pos_error = np.linalg.norm(s["body_pos"] - s["ref_pos"], axis=-1).mean(axis=1)
        # Failure statistics of the start bins.
        self.failures *= c.failure_decay
        failed = np.flatnonzero(done & ~unstable)
        np.add.at(self.failures, self.bin_offset[self.clip[failed]] + self.frame[failed] // self.bin_frames, 1.0)
        # Clips that reached their last frame go on with a random clip placed where the robot stands (its pelvis
        # xy and heading): drift accumulated over one clip is not carried into the next.
        self.clip_finished = (self.frame >= cl.length[self.clip] - 1) & ~done
        fin = np.flatnonzero(self.clip_finished)
        if fin.size:
            xy, yaw = self.sim.qpos[fin, :2], heading(self.sim.qpos[fin, 3:7])
            self._start_clip(fin, self._rng.integers(0, len(cl.length), size=fin.size), np.zeros(fin.size, np.int64),
                             xy, yaw)
            s = self._state()
        self.last_act = a
        next_obs, next_cobs = self._observe(s)
        self._push(done)
        out, n_unstable = base.finish_step(next_obs, next_cobs, reward, scaled, done, unstable,
                                           self.steps >= c.episode_length, self._reset_and_observe)
        self.unstable_count += n_unstable
        return out

    def eval_tracker(self) -> TrackingEval:
        """Switches the task to evaluation starts (env i: clip i mod n from frame 0, no noise; call before
        ``reset``) and returns the tracker of its metric."""
        self.play_from_start = True
        return TrackingEval(self)


class TrackingEval:
    """The tracking metric over each env's first clip while a caller steps the task (``step`` / ``result``
    like ``walking_metric.WalkingTracker``): ``clip_completion``, the fraction of envs whose first clip reached its
    last frame without termination, and ``body_pos_error``, the mean per-body position error (m, world
    frame) over the steps of those first clips."""

    LOGGED = ("body_pos_error", "clip_completion", "fall_rate")

    def __init__(self, task: G1Track):
        self._task = task
        m = task.num_envs
        self.active = np.ones(m, dtype=bool)
        self._completed = np.zeros(m, dtype=bool)
        self._fell = np.zeros(m, dtype=bool)
        self._error, self._count = 0.0, 0

    @property
    def done(self) -> bool:
        return not self.active.any()

    def step(self, action: np.ndarray) -> base.StepOut:
        task = self._task
        out = task.step(action)
        ended = out.terminated | out.truncated
        ok = self.active & ~ended
        self._error += float(task.body_pos_error[ok].sum())
        self._count += int(ok.sum())
        self._fell |= self.active & out.terminated
        self._completed |= ok & task.clip_finished
        self.active &= ~ended & ~task.clip_finished
        return out

    def result(self) -> dict[str, float]:
        return {"body_pos_error": self._error / self._count if self._count else math.nan,
                "clip_completion": float(self._completed.mean()), "fall_rate": float(self._fell.mean()),
                "evaluated_steps": self._count, "episodes": len(self._completed)}


def make(config: G1TrackConfig, num_envs: int, seed: int) -> G1Track:
    return G1Track(config, num_envs, seed)
