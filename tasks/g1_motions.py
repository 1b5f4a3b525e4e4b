"""G1 reference motions: keyframes turned into joint trajectories by inverse kinematics, and their clip format.

The clips the ``g1_track`` task follows are made here, from a few keyframes each, and committed under
``tasks/motions/`` (regenerate them with ``python -m tasks.g1_motions --out tasks/motions``).

Keyframes
    A clip is a list of keyframes ``(time s, targets)``; each keyframe changes some targets and keeps the
    others from the keyframe before. Targets (world frame, metres / radians): ``pelvis`` position, pelvis
    ``yaw`` and ``pitch``; ``lfoot`` / ``rfoot``: the position of the foot site (the middle of the sole's
    contact spheres, 5.5 mm above the floor when the foot stands) and ``lfoot_yaw`` / ``rfoot_yaw`` (feet
    stay flat); ``lhand`` / ``rhand``: the wrist-yaw link's position relative to the pelvis in the pelvis's
    heading frame. Each target moves between keyframes along a cubic Hermite curve whose end velocities
    are 0 unless a keyframe gives them (``vel``: both sides; ``vin`` / ``vout``: arriving / leaving).
    A cubic Hermite reproduces any parabola exactly, which makes the hop's flight ballistic: between take-off
    and landing the pelvis and both feet follow ``z(t) = z0 + v0 t - g t^2 / 2`` with the legs fixed relative
    to the pelvis, so the whole body (its centre of mass included) falls freely.

Inverse kinematics
    Per frame (50 fps), damped least squares (Levenberg-Marquardt) over the 35 velocity coordinates (free
    joint + 29 hinges) on weighted residuals: pelvis position and orientation, each foot's position and
    orientation (flat, at its yaw), each hand's position, and a posture prior pulling the joints towards the
    standing pose (strong on the waist, weak elsewhere); joint limits are enforced after every iteration.
    Each frame starts from the previous frame's solution. Joint velocities are central differences of the
    positions (``mj_differentiatePos``); body velocities come from ``mj_objectVelocity`` at those.

Clips (all start and end in the standing pose, so the task can chain them)
    ``squat`` (3 s): down to a pelvis height of 0.50 m with the torso leaning forward and arms reaching out.
    ``side_step`` (2.8 s): weight onto the right foot, left foot steps 0.1 m left, weight across, right foot
    follows. ``turn`` (4.3 s): two stepping turns of 45 degrees to the left. The ankle's roll range keeps the
    weight shift short of the stance foot (the centre of mass stays ~5 cm inside it), so the steps are quick
    (0.3 s swings, a controlled fall towards the landing foot as in a human side step). ``hop`` (2.4 s): crouch, push
    off to 0.98 m/s at a pelvis height of 0.75 m, 0.2 s of ballistic flight (4.9 cm apex), land, absorb, stand.
    No flip: a flip's flight must carry the angular momentum the take-off gave it (the rotation is set by the
    push-off, and the centre of mass follows a parabola); keyframes + IK prescribe poses, not momentum, so a
    kinematic flip clip would ask for root accelerations no contact can produce mid-air. Making one plausible
    needs trajectory optimisation through the contact dynamics, which this generator does not do.

Clip format (one ``.npz`` per clip, ``np.savez_compressed``, loaded by ``load_clip``; ``qpos`` float32, the
other arrays float16: about 0.5 mm and 1 mrad, 33-75 KB a clip)
    ``fps`` () float: frames per second (50, the task's control rate).
    ``joint_names`` [29] str: the hinge joints in qpos order (``qpos[:, 7:]``).
    ``body_names`` [B] str: the tracked bodies (``TRACKED_BODIES``); ``anchor_body`` () str: the task's anchor.
    ``qpos`` [T, 36]: free joint (x, y, z, quaternion w, x, y, z) then the joints; ``qvel`` [T, 35]: world
    linear velocity of the pelvis, its angular velocity in the pelvis frame (MuJoCo's free-joint convention),
    then joint velocities.
    ``body_pos`` [T, B, 3], ``body_quat`` [T, B, 4] (w, x, y, z), ``body_lin_vel`` / ``body_ang_vel`` [T, B, 3]:
    world-frame pose and velocity of each tracked body's frame.
    ``keyframe_frames`` [K] int: the frames of the keyframes (where the targets are met).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
from collections.abc import Mapping, Sequence

import mujoco
import numpy as np

from tasks import g1_walk, walking

FPS = 50.0
GRAVITY = 9.81
CLIP_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "motions")
ANCHOR_BODY = "torso_link"
TRACKED_BODIES = (
    "pelvis", "left_hip_roll_link", "left_knee_link", "left_ankle_roll_link", "right_hip_roll_link",
    "right_knee_link", "right_ankle_roll_link", "torso_link", "left_shoulder_roll_link", "left_elbow_link",
    "left_wrist_yaw_link", "right_shoulder_roll_link", "right_elbow_link", "right_wrist_yaw_link",
)
FOOT_SITES = {"lfoot": "left_foot", "rfoot": "right_foot"}
HAND_BODIES = {"lhand": "left_wrist_yaw_link", "rhand": "right_wrist_yaw_link"}
SOLE_Z = 0.00551  # foot-site height when the foot stands on the floor
STAND_Z = 0.757  # pelvis height of the standing pose
FOOT_Y = 0.1185
FOOT_X = 0.034
# Target name -> size.
TARGETS = {"pelvis": 3, "yaw": 1, "pitch": 1, "lfoot": 3, "lfoot_yaw": 1, "rfoot": 3, "rfoot_yaw": 1,
           "lhand": 3, "rhand": 3}
STAND = {"pelvis": (0.0, 0.0, STAND_Z), "yaw": 0.0, "pitch": 0.0, "lfoot": (FOOT_X, FOOT_Y, SOLE_Z),
         "lfoot_yaw": 0.0, "rfoot": (FOOT_X, -FOOT_Y, SOLE_Z), "rfoot_yaw": 0.0,
         "lhand": (0.10, 0.21, -0.03), "rhand": (0.10, -0.21, -0.03)}


@dataclasses.dataclass(frozen=True)
class Keyframe:
    """Targets at ``time`` (s) that change from the keyframe before; velocities per target (default 0)."""

    time: float
    targets: Mapping[str, float | Sequence[float]] = dataclasses.field(default_factory=dict)
    vel: Mapping[str, float | Sequence[float]] = dataclasses.field(default_factory=dict)
    vin: Mapping[str, float | Sequence[float]] = dataclasses.field(default_factory=dict)
    vout: Mapping[str, float | Sequence[float]] = dataclasses.field(default_factory=dict)


# --------------------------------------------------------------------------------------------------
# Keyframes of the clips
# --------------------------------------------------------------------------------------------------
def _squat() -> list[Keyframe]:
    low = {"pelvis": (-0.07, 0.0, 0.50), "pitch": 0.45, "lhand": (0.40, 0.18, 0.20), "rhand": (0.40, -0.18, 0.20)}
    return [Keyframe(0.0, STAND), Keyframe(0.4), Keyframe(1.3, low), Keyframe(1.7),
            Keyframe(2.6, {k: STAND[k] for k in low}), Keyframe(3.0)]


def _side_step(dy: float = 0.1, lift: float = 0.04, shift: float = 0.04) -> list[Keyframe]:
    # The ankle rolls only +-0.26 rad, so a flat foot can land at most ~0.2 m beside the hip: a small step with
    # the pelvis ``shift`` inside the stance foot's centre line.
    over_right, over_left = (0.0, -FOOT_Y + shift, STAND_Z), (0.0, FOOT_Y + dy - shift, STAND_Z)
    return [
        Keyframe(0.0, STAND), Keyframe(0.3),
        Keyframe(0.9, {"pelvis": over_right}),
        Keyframe(1.04, {"lfoot": (FOOT_X, FOOT_Y + dy / 2, lift)}),
        Keyframe(1.2, {"lfoot": (FOOT_X, FOOT_Y + dy, SOLE_Z)}),
        Keyframe(1.8, {"pelvis": over_left}),
        Keyframe(1.94, {"rfoot": (FOOT_X, -FOOT_Y + dy / 2, lift)}),
        Keyframe(2.1, {"rfoot": (FOOT_X, -FOOT_Y + dy, SOLE_Z)}),
        Keyframe(2.6, {"pelvis": (0.0, dy, STAND_Z)}), Keyframe(2.8),
    ]


def _rot(yaw: float, x: float, y: float) -> tuple[float, float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return c * x - s * y, s * x + c * y


def _turn(step: float = math.pi / 4, steps: int = 2) -> list[Keyframe]:
    keys, t = [Keyframe(0.0, STAND), Keyframe(0.3)], 0.3
    for k in range(steps):
        a0, a1 = k * step, (k + 1) * step
        foot = {side: [_rot(a, FOOT_X, sign * FOOT_Y) for a in (a0, a1)] for side, sign in (("l", 1), ("r", -1))}
        over = {side: _rot(a, 0.0, sign * 0.095) for side, a, sign in (("r", a0, -1), ("l", a1, 1))}
        mid = {s: ((foot[s][0][0] + foot[s][1][0]) / 2, (foot[s][0][1] + foot[s][1][1]) / 2) for s in "lr"}
        keys += [
            Keyframe(t + 0.5, {"pelvis": (*over["r"], 0.74)}),
            Keyframe(t + 0.64, {"lfoot": (*mid["l"], 0.05), "lfoot_yaw": (a0 + a1) / 2}),
            Keyframe(t + 0.8, {"lfoot": (*foot["l"][1], SOLE_Z), "lfoot_yaw": a1, "yaw": (a0 + a1) / 2}),
            Keyframe(t + 1.3, {"pelvis": (*over["l"], 0.74)}),
            Keyframe(t + 1.44, {"rfoot": (*mid["r"], 0.05), "rfoot_yaw": (a0 + a1) / 2}),
            Keyframe(t + 1.6, {"rfoot": (*foot["r"][1], SOLE_Z), "rfoot_yaw": a1, "yaw": a1}),
        ]
        t += 1.6
    return keys + [Keyframe(t + 0.5, {"pelvis": (0.0, 0.0, STAND_Z)}), Keyframe(t + 0.8)]


def _hop(crouch: float = 0.62, takeoff: float = 0.75, flight: float = 0.2) -> list[Keyframe]:
    v0 = GRAVITY * flight / 2  # take-off speed of a ballistic flight of `flight` seconds
    t_off = 1.04
    t_land = t_off + flight
    arms_back = {"lhand": (-0.05, 0.22, -0.08), "rhand": (-0.05, -0.22, -0.08)}
    arms_up = {"lhand": (0.18, 0.22, 0.02), "rhand": (0.18, -0.22, 0.02)}
    up = (0.0, 0.0, v0)
    return [
        Keyframe(0.0, STAND), Keyframe(0.2),
        Keyframe(0.8, {"pelvis": (-0.03, 0.0, crouch), "pitch": 0.3, **arms_back}),
        Keyframe(t_off, {"pelvis": (0.0, 0.0, takeoff), "pitch": 0.0, **arms_up}, vel={"pelvis": up},
                 vout={"lfoot": up, "rfoot": up}),
        Keyframe(t_land, {}, vel={"pelvis": (0.0, 0.0, -v0)}, vin={"lfoot": (0.0, 0.0, -v0), "rfoot": (0.0, 0.0, -v0)}),
        Keyframe(t_land + 0.3, {"pelvis": (-0.03, 0.0, crouch), "pitch": 0.3,
                                "lhand": (0.20, 0.22, 0.0), "rhand": (0.20, -0.22, 0.0)}),
        Keyframe(2.1, {k: STAND[k] for k in ("pelvis", "pitch", "lhand", "rhand")}), Keyframe(2.4),
    ]


CLIPS = {"squat": _squat, "side_step": _side_step, "turn": _turn, "hop": _hop}


# --------------------------------------------------------------------------------------------------
# Keyframes -> per-frame targets
# --------------------------------------------------------------------------------------------------
def _vector(values: Mapping[str, float | Sequence[float]]) -> dict[str, np.ndarray]:
    out = {}
    for name, v in values.items():
        if name not in TARGETS:
            raise ValueError(f"unknown target {name!r}; targets are {sorted(TARGETS)}")
        out[name] = np.broadcast_to(np.asarray(v, dtype=np.float64), (TARGETS[name],)).copy()
    return out


def target_trajectory(keyframes: Sequence[Keyframe], fps: float = FPS) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """({target: [T, size]} at every frame, keyframe frame indices [K]) of a keyframe list (its first keyframe
    at time 0 must set every target; times strictly increasing, frame-aligned)."""
    if keyframes[0].time != 0.0 or set(keyframes[0].targets) != set(TARGETS):
        raise ValueError("the first keyframe must be at time 0 and set every target")
    frames = np.array([round(k.time * fps) for k in keyframes])
    if np.any(np.diff(frames) <= 0) or not np.allclose(frames / fps, [k.time for k in keyframes], atol=1e-9):
        raise ValueError("keyframe times must increase and fall on frames")
    zero = {n: np.zeros(s) for n, s in TARGETS.items()}
    pos, vin, vout, current = [], [], [], {}
    for k in keyframes:
        current = {**current, **_vector(k.targets)}
        pos.append(current)
        vel = _vector(k.vel)
        vin.append({**zero, **vel, **_vector(k.vin)})
        vout.append({**zero, **vel, **_vector(k.vout)})
    out = {n: np.zeros((frames[-1] + 1, s)) for n, s in TARGETS.items()}
    for i in range(len(keyframes) - 1):
        f0, f1 = frames[i], frames[i + 1]
        dur = (f1 - f0) / fps
        s = (np.arange(f0, f1 + 1) - f0)[:, None] / (f1 - f0)
        h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
        h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
        for n in TARGETS:
            out[n][f0 : f1 + 1] = (h00 * pos[i][n] + h10 * dur * vout[i][n] + h01 * pos[i + 1][n]
                                   + h11 * dur * vin[i + 1][n])
    return out, frames


# --------------------------------------------------------------------------------------------------
# Inverse kinematics
# --------------------------------------------------------------------------------------------------
def _quat_yaw_pitch(yaw: float, pitch: float) -> np.ndarray:
    qy = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    qp = np.array([math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0])
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, qy, qp)
    return out


def _rot_error(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """World-frame rotation vector r with target = exp(r) * current."""
    inv, diff, r = np.zeros(4), np.zeros(4), np.zeros(3)
    mujoco.mju_negQuat(inv, current)
    mujoco.mju_mulQuat(diff, target, inv)
    mujoco.mju_quat2Vel(r, diff, 1.0)
    return r


class IKSolver:
    """Damped least squares on the pelvis, feet and hands targets of ``target_trajectory`` (see the module doc).

    ``model``: the G1 model (its first joint free); ``stand_qpos``: the standing pose (posture prior)."""

    W_POS, W_ROT, W_HAND = 10.0, 5.0, 1.0

    def __init__(self, model: mujoco.MjModel, stand_qpos: np.ndarray, damping: float = 1e-4,
                 iterations: int = 200, tol: float = 1e-7):
        self.m, self.d = model, mujoco.MjData(model)
        self.stand = np.asarray(stand_qpos, dtype=np.float64)
        self.damping, self.iterations, self.tol = damping, iterations, tol
        m = model
        self.pelvis = m.body("pelvis").id
        self.sites = {k: m.site(v).id for k, v in FOOT_SITES.items()}
        self.foot_bodies = {k: m.site_bodyid[i] for k, i in self.sites.items()}
        self.hands = {k: m.body(v).id for k, v in HAND_BODIES.items()}
        d = self.d
        d.qpos[:] = self.stand
        mujoco.mj_kinematics(m, d)
        self.foot_quat0 = {k: d.xquat[b].copy() for k, b in self.foot_bodies.items()}
        hinge = np.arange(1, m.njnt)
        self.qadr, self.vadr = m.jnt_qposadr[hinge], m.jnt_dofadr[hinge]
        self.lo, self.hi = m.jnt_range[hinge, 0], m.jnt_range[hinge, 1]
        # Posture prior weights: the waist holds the torso on the pelvis; the rest only breaks ties.
        self.w_posture = np.array([1.0 if "waist" in m.joint(j).name else 1e-3 for j in hinge])

    def residuals(self, targets: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(residuals r, Jacobian J [len r, nv], weights w) at the current ``self.d.qpos`` (kinematics done)."""
        m, d, nv = self.m, self.d, self.m.nv
        rows, jacs, ws = [], [], []
        jp, jr = np.zeros((3, nv)), np.zeros((3, nv))

        def add(r, jac, w):
            rows.append(r)
            jacs.append(jac.copy())
            ws.append(np.full(r.size, w))

        yaw = float(targets["yaw"][0])
        mujoco.mj_jacBody(m, d, jp, jr, self.pelvis)
        add(targets["pelvis"] - d.xpos[self.pelvis], jp, self.W_POS)
        add(_rot_error(_quat_yaw_pitch(yaw, float(targets["pitch"][0])), d.xquat[self.pelvis]), jr, self.W_ROT)
        for k, site in self.sites.items():
            mujoco.mj_jacSite(m, d, jp, jr, site)
            add(targets[k] - d.site_xpos[site], jp, self.W_POS)
            qt = np.zeros(4)
            mujoco.mju_mulQuat(qt, _quat_yaw_pitch(float(targets[f"{k}_yaw"][0]), 0.0), self.foot_quat0[k])
            add(_rot_error(qt, d.xquat[self.foot_bodies[k]]), jr, self.W_ROT)
        c, s = math.cos(yaw), math.sin(yaw)
        heading = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        for k, body in self.hands.items():
            mujoco.mj_jacBody(m, d, jp, jr, body)
            add(d.xpos[self.pelvis] + heading @ targets[k] - d.xpos[body], jp, self.W_HAND)
        posture = np.zeros((self.qadr.size, nv))
        posture[np.arange(self.qadr.size), self.vadr] = 1.0
        add(self.stand[self.qadr] - d.qpos[self.qadr], posture, 1.0)
        ws[-1] = self.w_posture
        return np.concatenate(rows), np.concatenate(jacs), np.concatenate(ws)

    def solve(self, targets: Mapping[str, np.ndarray], qpos0: np.ndarray) -> np.ndarray:
        """qpos meeting ``targets`` (one frame: {name: [size]}), starting from ``qpos0``."""
        m, d = self.m, self.d
        d.qpos[:] = qpos0
        for _ in range(self.iterations):
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            r, jac, w = self.residuals(targets)
            jw = jac * w[:, None]
            dq = np.linalg.solve(jac.T @ jw + self.damping * np.eye(m.nv), jw.T @ r)
            mujoco.mj_integratePos(m, d.qpos, dq, 1.0)
            d.qpos[self.qadr] = np.clip(d.qpos[self.qadr], self.lo, self.hi)
            if dq @ dq < self.tol**2:
                break
        return d.qpos.copy()


# --------------------------------------------------------------------------------------------------
# Clips
# --------------------------------------------------------------------------------------------------
def standing_qpos(model: mujoco.MjModel) -> np.ndarray:
    """``g1_walk``'s default pose with the pelvis at the height where the feet touch the floor."""
    qpos = model.qpos0.copy()
    for name, angle in g1_walk.DEFAULT_POSE.items():
        qpos[model.jnt_qposadr[model.joint(name).id]] = angle
    bodies = {model.body(b).id for b in g1_walk.FOOT_BODIES}
    feet = [g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies]
    qpos[2] = walking.standing_height(model, qpos, feet)
    return qpos


def g1_model() -> tuple[mujoco.MjModel, np.ndarray]:
    """The G1 model of the G1 tasks (``g1_walk_flat``'s MjSpec edits; the kinematics are the MJCF's) and its
    standing qpos."""
    model = g1_walk.build_spec(g1_walk.default_config()).compile()
    return model, standing_qpos(model)


def make_clip(model: mujoco.MjModel, stand_qpos: np.ndarray, keyframes: Sequence[Keyframe],
              fps: float = FPS) -> dict[str, np.ndarray]:
    """The clip arrays (module doc's format) of ``keyframes``."""
    targets, key_frames = target_trajectory(keyframes, fps)
    T = key_frames[-1] + 1
    ik = IKSolver(model, stand_qpos)
    qpos = np.zeros((T, model.nq))
    q = stand_qpos.copy()
    for f in range(T):
        q = ik.solve({n: v[f] for n, v in targets.items()}, q)
        qpos[f] = q
    qvel = np.zeros((T, model.nv))
    for f in range(T):
        a, b = max(f - 1, 0), min(f + 1, T - 1)
        mujoco.mj_differentiatePos(model, qvel[f], (b - a) / fps, qpos[a], qpos[b])
    bodies = [model.body(b).id for b in TRACKED_BODIES]
    d = mujoco.MjData(model)
    B = len(bodies)
    pos, quat, lin, ang = np.zeros((T, B, 3)), np.zeros((T, B, 4)), np.zeros((T, B, 3)), np.zeros((T, B, 3))
    vel6 = np.zeros(6)
    for f in range(T):
        d.qpos[:], d.qvel[:] = qpos[f], qvel[f]
        mujoco.mj_forward(model, d)
        pos[f], quat[f] = d.xpos[bodies], d.xquat[bodies]
        for i, b in enumerate(bodies):
            mujoco.mj_objectVelocity(model, d, mujoco.mjtObj.mjOBJ_XBODY, b, vel6, 0)
            ang[f, i], lin[f, i] = vel6[:3], vel6[3:]
    joints = [model.joint(j).name for j in range(1, model.njnt)]
    f32, f16 = np.float32, np.float16
    return {"fps": np.array(fps), "joint_names": np.array(joints), "body_names": np.array(TRACKED_BODIES),
            "anchor_body": np.array(ANCHOR_BODY), "qpos": qpos.astype(f32), "qvel": qvel.astype(f16),
            "body_pos": pos.astype(f16), "body_quat": quat.astype(f16), "body_lin_vel": lin.astype(f16),
            "body_ang_vel": ang.astype(f16), "keyframe_frames": key_frames.astype(np.int32)}


def load_clip(path: str) -> dict[str, np.ndarray]:
    """One clip file's arrays (module doc's format), checked for consistent shapes."""
    with np.load(path, allow_pickle=False) as z:
        clip = {k: z[k] for k in z.files}
    missing = {"fps", "joint_names", "body_names", "anchor_body", "qpos", "qvel", "body_pos", "body_quat",
               "body_lin_vel", "body_ang_vel"} - set(clip)
    if missing:
        raise ValueError(f"{path}: not a clip file, missing {sorted(missing)}")
    T, B = clip["qpos"].shape[0], clip["body_names"].size
    shapes = {"qpos": (T, 7 + clip["joint_names"].size), "qvel": (T, 6 + clip["joint_names"].size),
              "body_pos": (T, B, 3), "body_quat": (T, B, 4), "body_lin_vel": (T, B, 3), "body_ang_vel": (T, B, 3)}
    for k, shape in shapes.items():
        if clip[k].shape != shape:
            raise ValueError(f"{path}: {k} has shape {clip[k].shape}, expected {shape}")
    if T < 2:
        raise ValueError(f"{path}: a clip needs at least 2 frames")
    return clip


def clip_paths(directory: str = CLIP_DIR) -> list[str]:
    """The ``.npz`` clips of ``directory``, sorted by name."""
    return sorted(os.path.join(directory, f) for f in os.listdir(directory) if f.endswith(".npz"))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default=CLIP_DIR, help="folder the clips are written to")
    parser.add_argument("--clips", default=",".join(CLIPS), help=f"comma-separated subset of {list(CLIPS)}")
    args = parser.parse_args(argv)
    names = [n for n in args.clips.split(",") if n]
    unknown = sorted(set(names) - set(CLIPS))
    if unknown:
        parser.error(f"unknown clips {unknown}; choose from {list(CLIPS)}")
    os.makedirs(args.out, exist_ok=True)
    model, stand = g1_model()
    for name in names:
        clip = make_clip(model, stand, CLIPS[name]())
        path = os.path.join(args.out, f"{name}.npz")
        np.savez_compressed(path, **clip)
        print(f"{path}: {clip['qpos'].shape[0]} frames, {os.path.getsize(path) / 1024:.0f} KB")


if __name__ == "__main__":
    main()
