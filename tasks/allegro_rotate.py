"""``allegro_rotate``: in-hand rotation of objects about the vertical axis with a palm-up Allegro hand (HORA's task).

After HORA (Qi et al., CoRL 2022, arXiv 2210.04887), rebuilt on MuJoCo with Menagerie's ``wonik_allegro``:

* Model: Menagerie's ``scene_right`` loaded through ``mujoco_menagerie`` and edited with ``mujoco.MjSpec``.
  The hand is palm up as Menagerie places it (fingers along world +x, flexion curls them up). Its scene
  object and floor are removed; an ``object`` body with a free joint holds one geom per shape in
  ``config.shapes`` (an upright cylinder and/or a box). Only object-hand contacts exist (hand geoms
  contype 1 / conaffinity 0, object geoms 0 / 1; condim 3; the object has priority over the fingers, so
  its friction applies there, and the palm over the object). Visual meshes are stripped after the
  bodies' inertials are fixed from the full model.
  Position actuators ``tau = kp (target - q) - kd qdot`` with HORA's gains (kp 3, kd 0.1), torque
  limit 0.7 N m, joint damping 0 (kd is the actuator's), armature 1e-3 (see ``ARMATURE``); sim_dt 0.005,
  ``implicitfast``, Newton 20 / 10 iterations, pyramidal cone (MJX needs it).
* Control: 20 Hz (ctrl_dt 0.05, 10 substeps), HORA's relative targets:
  ``target = clip(previous target + action_scale * action, joint range)`` with action_scale 1/24.
  Episode 400 steps (20 s), HORA's.
* Initial state (HORA starts from cached grasps): the object rests on the palm (``PALM_CENTER``, 3 cm from
  the finger roots) with a random yaw, the hand at the canonical pose ``CANONICAL_POSE`` (+ U(+-0.05) rad):
  fingers raised beside the object with the fingertips curled over its top edge, thumb rotated out. It was
  chosen by simulation instead of a settle at every reset (a scan of finger poses by the fingers' distance
  to the nominal object: middle finger 0.2 mm, index / ring 5 mm away): with the largest object no hand
  geom penetrates it by more than 1.2 mm, and under zero actions no object fell (8 envs x 100 steps, the
  smallest and the largest size); a thumb rotated further in (0.6-1.0 rad) intersected the object and
  pushed it off the palm. The targets start at the reset pose, the index / middle / ring medial and distal
  ones ``reset_press`` rad past it (ours: the fingers press on the object's top edge from the first step).
  The palm's contacts use its own low friction (0.2, ``PALM_FRICTION``; the fingers' use the object's), so
  the fingers can turn an object that rests on it. With ``grasp_cache`` an episode starts instead from a
  cached grasp (``tasks/allegro_grasps.py``: hand joints, the targets that hold the object, and the object),
  HORA's start; the grasps press the object onto the palm with two or more fingers.
* Objects, drawn per episode (each env simulates its own ``MjModel`` copy, whose object fields are
  rewritten at its reset; nothing is recompiled): shape uniform over ``config.shapes``; size scale
  U(0.85, 1.1) of the nominal cylinder (radius 0.03, half-height 0.025) / box (half-sides 0.026, 0.026,
  0.025); mass U(0.03, 0.12) kg with the solid's inertia; centre of mass + U(+-0.01) m; friction
  U(0.5, 1.2). The inactive shape's geom is parked 1 m below the object (no contact can reach it).
* Actor observation (48), one HORA frame: joint angles - canonical 16 (noise U(+-0.01)), joint
  velocities 16 (noise U(+-0.1)), previous targets - canonical 16; with ``actor_extrinsics`` followed by the
  extrinsics (below, noise-free): a privileged actor, which the PPO recipe uses (the HORA recipe keeps the
  frames proprioceptive and gives its teacher the extrinsics through z).
* Critic observation (88): the clean frame 48, object position relative to the palm centre 3, object
  quaternion 4 (w >= 0), object linear / angular velocity over the last step 3 + 3, actuator torques 16,
  and the extrinsics 11.
* Extrinsics (``self.extrinsics [M, 11]``, HORA's privileged vector): mass 1, centre-of-mass offset 3,
  friction 1, size scale 1, shape one-hot 2 (``SHAPES`` order), object position relative to the palm
  centre 3 (a property, read each step). With ``object_state_extrinsics`` (ours; [M, 21]) also the object's
  quaternion (w >= 0) 4 and its finite-difference linear and angular velocity over the last step 3 + 3 (0
  after a reset): the state a teacher needs to close the loop on the rotation.
* Reward per step = sum(scale * term), not multiplied by dt (HORA's convention), terms in
  ``REWARD_SCALES``: ``rotate`` = clip(object angular velocity about world z, -0.5, 0.5) rad/s, the
  velocity being the finite difference of the orientation over the control step as in HORA;
  ``object_linvel`` = L1 norm of the object's finite-difference linear velocity; ``pose_diff`` =
  sum (q - canonical)^2; ``torque`` = sum tau^2; ``work`` = (tau . qdot)^2 (HORA's definition; the
  absolute power |tau . qdot| squared); ``fall`` = 1 on the step the object falls. Scales are HORA's
  (1, -0.3, -0.3, -0.1, -2) plus fall -10 (ours: without it a policy that is still penalised more than it
  earns prefers to drop the object). The experiment recipes set the four penalties to 0 (measured: with
  them PPO settles on a still hand; docs/RESULTS.md "In-hand rotation (Allegro)").
* Termination (fall): object centre below the palm surface or more than 0.09 m (horizontally) from the
  palm centre. Time limit 400 steps (truncation).
* Evaluation metrics (``eval_tracker()`` -> ``tasks.allegro_metric.RotationTracker``, the trainer's
  ``eval/*``): ``rotation_rate`` (mean object angular velocity about z over the alive steps of each env's first
  episode, rad/s, unclipped) and its standard error over the episodes, ``rotation_episode`` (the yaw turned over
  the whole time limit per second, 0 after a fall), ``time_to_fall`` (mean fraction of the episode before a fall;
  1 without one), plus ``rotate_reward`` (mean per-step rotation reward term).

The observation/reward math is module-level functions written against the shim (``step_math``,
``observe``, ``reward_terms``, ``object_fields``), which ``tasks/mjx_allegro.py`` runs on jax arrays.
Deviations from HORA: the object rests on the palm instead of being held by the fingertips alone (a still
hand does not drop it, so rotation, not holding, is what must be learned; the grasp cache is an option); the
fall penalty is ours; so are the object's orientation and velocities in the extrinsics and the privileged
PPO actor (``object_state_extrinsics``, ``actor_extrinsics``). In the history variant, ``HistoryTask``
appends the extrinsics read after the auto-reset, so an ended env's ``next_obs`` extrinsics (its object
position) are the new episode's; this task's own critic observation has the true successor's.
"""

from __future__ import annotations

import copy
import dataclasses
import math

import mujoco
import numpy as np

from tasks import allegro_grasps, base
from tasks.allegro_metric import RotationTracker
from tasks.floating_base import quat_mul
from tasks.model_edits import load_menagerie_spec, sensor_index, set_solver, strip_visuals
from tasks.physics import BatchedSim
from unilab_jax import xp as shim

NAME = "allegro_rotate"
SHAPES = ("cylinder", "box")
REWARD_SCALES = {"rotate": 1.0, "object_linvel": -0.3, "pose_diff": -0.3, "torque": -0.1, "work": -2.0,
                 "fall": -10.0}
REWARD_TERMS = tuple(REWARD_SCALES)
NJ = 16
FRAME_DIM = 3 * NJ  # 48
EXTRINSICS_DIM = 1 + 3 + 1 + 1 + len(SHAPES) + 3  # 11
CRITIC_OBS_DIM = FRAME_DIM + 3 + 4 + 3 + 3 + NJ + EXTRINSICS_DIM  # 88
OBJECT_STATE_DIM = 4 + 3 + 3  # quaternion, linear, angular velocity: the extrinsics' tail (object_state_extrinsics)
# Index / middle / ring: spread 0, proximal, medial, distal; thumb: rotation, abduction, medial, distal.
CANONICAL_POSE = (0.0, 1.2, 1.2, 0.8) * 3 + (0.3, 0.4, 0.3, 0.3)
PALM_CENTER = (-0.03, 0.0)  # world xy of the object's rest position (on the palm, 3 cm from the finger roots)
PALM_TOP = 0.0114  # world z of the palm collision box's upper face
NOMINAL_SIZE = {"cylinder": (0.03, 0.025, 0.0), "box": (0.026, 0.026, 0.025)}
PALM_FRICTION = 0.2  # the palm's contacts use it (priority 2): a low-friction support the fingers turn the object on
ARMATURE = 1e-3  # rotor inertia: keeps kp 3 on the ~2e-5 kg m^2 finger links stable at sim_dt 0.005
PARKED = -1.0  # z offset (m) of the inactive shape's geom


@base.with_reward_scales(REWARD_SCALES)
@dataclasses.dataclass(frozen=True)
class AllegroRotateConfig:
    """Configuration of ``allegro_rotate`` (override any field by name)."""

    episode_length: int = 400
    ctrl_dt: float = 0.05
    sim_dt: float = 0.005
    kp: float = 3.0
    kd: float = 0.1
    torque_limit: float = 0.7
    action_scale: float = 1.0 / 24.0
    solver_iterations: int = 20
    ls_iterations: int = 10
    integrator: str = "implicitfast"
    shapes: tuple[str, ...] = SHAPES  # object shapes drawn from (MJX: ("box",), see tasks/mjx_allegro.py)
    # Observation noise: U(-1, 1) * noise_level * scale.
    noise_level: float = 1.0
    noise_joint_pos: float = 0.01
    noise_joint_vel: float = 0.1
    # Privileged inputs (see the module docstring): the extrinsics also hold the object's quaternion, linear and
    # angular velocity (HORA's vector has its position only); the actor's observation ends with the extrinsics.
    object_state_extrinsics: bool = False
    actor_extrinsics: bool = False
    # Reward.
    angvel_clip: tuple[float, float] = (-0.5, 0.5)
    # Reset and termination.
    reset_pose_noise: float = 0.05
    # Added to the reset targets (not the joints) of the index, middle and ring fingers' medial and distal
    # joints (rad): the fingers start pressing on the object's top edge instead of resting at it.
    reset_press: float = 0.0
    # "": the palm start above; "builtin", "held" or a .npz path: episodes start from a cached grasp (HORA's start,
    # tasks/allegro_grasps.py), which sets the hand, its targets and the object (reset_press must be 0).
    grasp_cache: str = ""
    fall_radius: float = 0.09
    # Object randomisation (per episode).
    domain_randomization: bool = True
    dr_scale: tuple[float, float] = (0.85, 1.1)
    dr_mass: tuple[float, float] = (0.03, 0.12)
    dr_com_offset: float = 0.01
    dr_friction: tuple[float, float] = (0.5, 1.2)
    physics_engine: str = "rollout"


def default_config() -> AllegroRotateConfig:
    return AllegroRotateConfig()


def reward_scales(config: AllegroRotateConfig) -> dict[str, float]:
    return base.reward_scales(config, REWARD_TERMS)


def extrinsics_dim(config: AllegroRotateConfig) -> int:
    return EXTRINSICS_DIM + (OBJECT_STATE_DIM if config.object_state_extrinsics else 0)


def actor_obs_dim(config: AllegroRotateConfig) -> int:
    return FRAME_DIM + (extrinsics_dim(config) if config.actor_extrinsics else 0)


def check_config(config: AllegroRotateConfig) -> int:
    """Validates ``config``; returns the substeps per control step."""
    nsub = round(config.ctrl_dt / config.sim_dt)
    if nsub < 1 or abs(nsub * config.sim_dt - config.ctrl_dt) > 1e-9:
        raise ValueError(f"ctrl_dt {config.ctrl_dt} must be a multiple of sim_dt {config.sim_dt}")
    shapes = tuple(config.shapes)
    if not shapes or any(s not in SHAPES for s in shapes) or len(set(shapes)) != len(shapes):
        raise ValueError(f"shapes {config.shapes!r}: a non-empty subset of {SHAPES}")
    if config.grasp_cache and config.reset_press != 0.0:
        raise ValueError("grasp_cache sets the reset targets (the grasp's): reset_press must be 0")
    return nsub


# --------------------------------------------------------------------------------------------------
# Model
# --------------------------------------------------------------------------------------------------
def build_spec(config: AllegroRotateConfig) -> mujoco.MjSpec:
    """The palm-up hand with one object body (a geom per shape of ``config.shapes``), from Menagerie's scene."""
    spec = load_menagerie_spec("wonik_allegro", "scene_right")
    full = spec.compile()
    # Fix every body's inertia from the full model before the visual meshes (which carry the mass) go.
    for b in spec.bodies[1:]:
        mb = full.body(b.name)
        b.mass, b.ipos, b.iquat, b.inertia = float(mb.mass[0]), list(mb.ipos), list(mb.iquat), list(mb.inertia)
        b.explicitinertial = True
    spec.delete(spec.body("object"))
    spec.delete(spec.geom("floor"))
    strip_visuals(spec)
    set_solver(spec, config)
    spec.option.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
    for g in spec.geoms:
        g.contype, g.conaffinity, g.margin = 1, 0, 0.0
    palm = next(g for g in spec.geoms if g.parent.name == "palm")
    palm.priority, palm.friction = 2, [PALM_FRICTION, 0.005, 0.0001]
    for j in spec.joints:
        j.damping = np.zeros_like(np.asarray(j.damping))
        j.armature = ARMATURE
    for a in spec.actuators:
        a.gainprm[0] = config.kp
        a.biasprm[1] = -config.kp
        a.biasprm[2] = -config.kd
        a.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        a.forcerange = [-config.torque_limit, config.torque_limit]
    r, h, _ = NOMINAL_SIZE["cylinder"]
    obj = spec.worldbody.add_body(name="object", pos=[PALM_CENTER[0], PALM_CENTER[1], PALM_TOP + h + 0.002])
    obj.add_freejoint(name="object")
    obj.mass, obj.inertia, obj.explicitinertial = 0.05, [1e-5, 1e-5, 1e-5], True
    types = {"cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER, "box": mujoco.mjtGeom.mjGEOM_BOX}
    for shape in config.shapes:
        obj.add_geom(name=shape, type=types[shape], size=list(NOMINAL_SIZE[shape]), contype=0, conaffinity=1,
                     condim=3, priority=1, friction=[1.0, 0.005, 0.0001], rgba=[0.8, 0.4, 0.2, 1.0])
    for a in spec.actuators:
        spec.add_sensor(name=f"{a.name}_torque", type=mujoco.mjtSensor.mjSENS_ACTUATORFRC,
                        objtype=mujoco.mjtObj.mjOBJ_ACTUATOR, objname=a.name)
    return spec


def object_fields(active, scale, mass, com, friction, nominal, kinds):
    """The object's per-episode model fields from its draws (shim-written: numpy or jax arrays).

    ``active [n, G]`` one-hot over the model's object geoms (``kinds``: their shapes, in geom order,
    ``nominal [G, 3]`` their nominal sizes); ``scale``, ``mass``, ``friction`` [n]; ``com`` [n, 3].
    Returns ``geom_size``, ``geom_pos``, ``geom_aabb`` [n, G, 3 or 6], ``geom_rbound`` [n, G],
    ``geom_friction`` [n, G, 3], ``body_mass`` [n], ``body_inertia`` [n, 3] (the active solid's) and
    ``body_ipos`` [n, 3]; the inactive geoms sit ``PARKED`` m below the body.
    """
    xp = shim.namespace(active, scale, mass, com, friction)
    size = scale[:, None, None] * nominal[None]
    half, rbound, inertia = [], [], 0.0
    for g, kind in enumerate(kinds):
        a, b, c = size[:, g, 0], size[:, g, 1], size[:, g, 2]
        if kind == "cylinder":  # radius a, half-height b
            half.append(xp.stack([a, a, b], axis=-1))
            rbound.append(xp.sqrt(a * a + b * b))
            lateral = mass * (3 * a * a + 4 * b * b) / 12
            solid = xp.stack([lateral, lateral, mass * a * a / 2], axis=-1)
        else:  # box with half-sides a, b, c
            half.append(size[:, g])
            rbound.append(xp.sqrt(a * a + b * b + c * c))
            solid = xp.stack([b * b + c * c, a * a + c * c, a * a + b * b], axis=-1) * (mass / 3)[:, None]
        inertia = inertia + active[:, g : g + 1] * solid
    half = xp.stack(half, axis=1)
    zeros = xp.zeros_like(half)
    parked = xp.stack([zeros[..., 0], zeros[..., 1], (1.0 - active) * PARKED], axis=-1)
    ones = xp.ones_like(active)
    fric = xp.stack([friction[:, None] * ones, 0.005 * ones, 0.0001 * ones], axis=-1)
    return {"geom_size": size, "geom_pos": parked, "geom_aabb": xp.concat([zeros, half], axis=-1),
            "geom_rbound": xp.stack(rbound, axis=1), "geom_friction": fric, "body_mass": mass,
            "body_inertia": inertia, "body_ipos": com}


def shape_one_hot(active, kinds):
    """[n, len(SHAPES)] one-hot of the active geom's shape (``active [n, G]`` over geoms of shapes ``kinds``)."""
    xp = shim.namespace(active)
    cols = [xp.sum(active[:, [g for g, k in enumerate(kinds) if k == s]], axis=1) if s in kinds
            else xp.zeros_like(active[:, 0]) for s in SHAPES]
    return xp.stack(cols, axis=-1)


# --------------------------------------------------------------------------------------------------
# Task math on the shim. Shapes: [M, ...] batched over envs; quaternions (w, x, y, z).
# --------------------------------------------------------------------------------------------------
def quat_conj(q):
    xp = shim.namespace(q)
    return xp.concat([q[:, :1], -q[:, 1:]], axis=-1)


def rotation_vector(q):
    """Axis * angle (angle in [0, pi]) of unit quaternions q [M, 4]."""
    xp = shim.namespace(q)
    sign = xp.where(q[:, :1] < 0, -xp.ones_like(q[:, :1]), xp.ones_like(q[:, :1]))
    w, v = q[:, :1] * sign, q[:, 1:] * sign
    n = xp.sqrt(xp.sum(xp.square(v), axis=-1, keepdims=True))
    small = n < 1e-8
    safe_n = xp.where(small, xp.ones_like(n), n)
    factor = xp.where(small, 2.0 / xp.maximum(w, xp.full_like(w, 1e-8)), 2.0 * xp.atan2(n, w) / safe_n)
    return v * factor


def object_motion(pos, quat, prev_pos, prev_quat, dt: float):
    """Finite-difference (linear, angular) velocity [M, 3] each, world frame, over one control step."""
    return (pos - prev_pos) / dt, rotation_vector(quat_mul(quat, quat_conj(prev_quat))) / dt


def actor_frame(joint_pos, joint_vel, target, canonical, noise):
    """HORA's proprioceptive frame (48): joint angles and velocities (+ noise [M, 32]), previous targets."""
    xp = shim.namespace(joint_pos, joint_vel, target, noise)
    return xp.concat([joint_pos - canonical + noise[:, :NJ], joint_vel + noise[:, NJ:], target - canonical], axis=-1)


def extrinsics(params, rel_pos):
    """[M, 11]: ``params [M, 8]`` (mass, com 3, friction, scale, shape one-hot 2) then the object position."""
    return shim.namespace(params, rel_pos).concat([params, rel_pos], axis=-1)


def task_extrinsics(params, rel_pos, quat, linvel, angvel, object_state: bool):
    """The task's extrinsics: ``extrinsics`` [M, 11], with ``object_state`` followed by the object's quaternion
    (w >= 0), linear and angular velocity [M, 10]."""
    ext = extrinsics(params, rel_pos)
    if not object_state:
        return ext
    return shim.namespace(ext, quat).concat([ext, positive_w(quat), linvel, angvel], axis=-1)


def positive_w(quat):
    """``quat`` with w >= 0 (the same rotation)."""
    xp = shim.namespace(quat)
    return quat * xp.where(quat[:, :1] < 0, -xp.ones_like(quat[:, :1]), xp.ones_like(quat[:, :1]))


def critic_obs(clean_frame, rel_pos, quat, linvel, angvel, torque, ext):
    xp = shim.namespace(clean_frame, quat)
    return xp.concat([clean_frame, rel_pos, positive_w(quat), linvel, angvel, torque, ext], axis=-1)


def fell(rel_pos, radius: float):
    """[M] bool: the object's centre is below the palm surface or ``radius`` m (horizontally) from its centre."""
    xp = shim.namespace(rel_pos)
    return (rel_pos[:, 2] < 0.0) | (xp.sqrt(xp.sum(xp.square(rel_pos[:, :2]), axis=-1)) > radius)


def reward_terms(*, angvel, linvel, joint_pos, joint_vel, canonical, torque, done, clip: tuple[float, float]):
    """Unscaled reward terms, each [M] (HORA's, plus the fall indicator)."""
    xp = shim.namespace(angvel, linvel, joint_pos, torque)
    lo, hi = clip
    return {
        "rotate": xp.clip(angvel[:, 2], lo, hi),
        "object_linvel": xp.sum(xp.abs(linvel), axis=-1),
        "pose_diff": xp.sum(xp.square(joint_pos - canonical), axis=-1),
        "torque": xp.sum(xp.square(torque), axis=-1),
        "work": xp.square(xp.sum(torque * joint_vel, axis=-1)),
        "fall": xp.astype(done, joint_pos.dtype),
    }


def scale_terms(terms, scales):
    """{name: scale * term}."""
    return {k: terms[k] * scales[k] for k in terms}


def total_reward(scaled):
    xp = shim.namespace(*scaled.values())
    return xp.sum(xp.stack(list(scaled.values()), axis=0), axis=0)


def relative_position(obj_pos, palm):
    """Object position relative to the palm centre ``palm [3]`` (rest xy, palm surface z)."""
    return obj_pos - palm


def observe(joint_pos, joint_vel, obj_pos, obj_quat, torque, target, linvel, angvel, params, noise, consts,
            config: AllegroRotateConfig):
    """(actor obs [M, 48] (then the task's extrinsics with ``config.actor_extrinsics``), critic obs [M, 88])."""
    xp = shim.namespace(joint_pos, noise)
    rel = relative_position(obj_pos, consts["palm"])
    zero = noise * 0.0
    obs = actor_frame(joint_pos, joint_vel, target, consts["canonical"], noise)
    if config.actor_extrinsics:
        ext = task_extrinsics(params, rel, obj_quat, linvel, angvel, config.object_state_extrinsics)
        obs = xp.concat([obs, ext], axis=-1)
    clean = actor_frame(joint_pos, joint_vel, target, consts["canonical"], zero)
    return obs, critic_obs(clean, rel, obj_quat, linvel, angvel, torque, extrinsics(params, rel))


def step_math(joint_pos, joint_vel, obj_pos, obj_quat, torque, info, params, noise, consts,
              config: AllegroRotateConfig, scales, dt: float):
    """Everything a control step computes after the physics; shared by the CPU task and ``tasks/mjx_allegro.py``.

    ``info``: ``target`` (the targets this step applied), ``obj_pos`` / ``obj_quat`` (the object before the
    step); ``params [M, 8]`` the episode's object parameters; ``noise [M, 32]`` scaled observation noise.
    Returns (next_obs, next_cobs, done [M] bool, scaled terms, reward [M], (object linear, angular velocity)
    [M, 3] each).
    """
    linvel, angvel = object_motion(obj_pos, obj_quat, info["obj_pos"], info["obj_quat"], dt)
    next_obs, next_cobs = observe(joint_pos, joint_vel, obj_pos, obj_quat, torque, info["target"], linvel, angvel,
                                  params, noise, consts, config)
    done = fell(relative_position(obj_pos, consts["palm"]), config.fall_radius)
    terms = reward_terms(angvel=angvel, linvel=linvel, joint_pos=joint_pos, joint_vel=joint_vel,
                         canonical=consts["canonical"], torque=torque, done=done, clip=tuple(config.angvel_clip))
    scaled = scale_terms(terms, scales)
    return next_obs, next_cobs, done, scaled, total_reward(scaled), (linvel, angvel)


def press_offset(reset_press: float):
    """[16] the reset targets' offset from the reset pose: ``reset_press`` on the fingers' medial and distal joints."""
    return np.array([0.0, 0.0, reset_press, reset_press] * 3 + [0.0] * 4)


def next_targets(target, action, action_scale: float, lower, upper):
    """HORA's relative position targets: clip(previous + action_scale * action, joint range)."""
    xp = shim.namespace(target, action)
    return xp.clip(target + action_scale * action, lower, upper)


def yaw_quat(yaw):
    """[n, 4] quaternions of rotations by ``yaw [n]`` about z."""
    xp = shim.namespace(yaw)
    zeros = xp.zeros_like(yaw)
    return xp.stack([xp.cos(yaw / 2), zeros, zeros, xp.sin(yaw / 2)], axis=-1)


# --------------------------------------------------------------------------------------------------
# The numpy task
# --------------------------------------------------------------------------------------------------
class AllegroRotate(base.Task):
    def __init__(self, config: AllegroRotateConfig, num_envs: int, seed: int):
        super().__init__(config, num_envs, seed)
        c = config
        nsub = check_config(c)
        self.dt = c.ctrl_dt
        self.model = build_spec(c).compile()
        m = self.model
        M = self.num_envs
        self._rng = np.random.Generator(np.random.Philox(self.seed))
        self.kinds = tuple(c.shapes)
        self.obj_body = m.body("object").id
        self.obj_geoms = np.array([m.geom(k).id for k in self.kinds])
        self.nominal = np.array([NOMINAL_SIZE[k] for k in self.kinds])
        self.lower, self.upper = m.actuator_ctrlrange.T.copy()
        self.consts = {"canonical": np.array(CANONICAL_POSE), "palm": np.array([*PALM_CENTER, PALM_TOP])}
        self._sensor = sensor_index(m)
        self.scales = reward_scales(c)
        self._noise_scale = np.r_[np.full(NJ, c.noise_joint_pos), np.full(NJ, c.noise_joint_vel)] * c.noise_level
        # One model copy per env: the object's fields are rewritten at each of its resets.
        self.sim = BatchedSim(m, M, nsub, engine=c.physics_engine, models=[copy.copy(m) for _ in range(M)])
        self.spec = base.TaskSpec(
            name=NAME, obs_dim=actor_obs_dim(c), critic_obs_dim=CRITIC_OBS_DIM, action_dim=NJ,
            episode_length=c.episode_length, ctrl_dt=c.ctrl_dt, reward_terms=REWARD_TERMS,
            privileged_dim=extrinsics_dim(c),
        )
        self.params = np.zeros((M, EXTRINSICS_DIM - 3))  # mass, com 3, friction, scale, shape one-hot 2
        self.info = {"target": np.zeros((M, NJ)), "obj_pos": np.zeros((M, 3)), "obj_quat": np.zeros((M, 4))}
        self.object_vel = np.zeros((M, 6))  # the object's linear, angular velocity over the last step
        self.steps = np.zeros(M, dtype=np.int64)
        self.unstable_count = 0
        self.grasps = allegro_grasps.load(c) if c.grasp_cache else None

    # ---- object randomisation -------------------------------------------------------------------
    def sample_objects(self, n: int) -> dict[str, np.ndarray]:
        """Per-episode object draws: ``active [n, G]`` one-hot, ``scale``, ``mass``, ``friction`` [n],
        ``com`` [n, 3]."""
        c, r = self.config, self._rng
        shape = r.integers(0, len(self.kinds), size=n)
        active = np.eye(len(self.kinds))[shape]
        if not c.domain_randomization:
            return {"active": active, "scale": np.ones(n), "mass": np.full(n, 0.06), "friction": np.full(n, 1.0),
                    "com": np.zeros((n, 3))}
        return {"active": active, "scale": r.uniform(*c.dr_scale, size=n), "mass": r.uniform(*c.dr_mass, size=n),
                "friction": r.uniform(*c.dr_friction, size=n),
                "com": r.uniform(-c.dr_com_offset, c.dr_com_offset, size=(n, 3))}

    def set_objects(self, idx: np.ndarray, draws: dict[str, np.ndarray]) -> None:
        """Writes the object draws of envs ``idx`` into their models and ``self.params``."""
        f = object_fields(draws["active"], draws["scale"], draws["mass"], draws["com"], draws["friction"],
                          self.nominal, self.kinds)
        g, b = self.obj_geoms, self.obj_body
        for k, i in enumerate(idx):
            mi = self.sim.models[i]
            for name in ("geom_size", "geom_pos", "geom_aabb", "geom_rbound", "geom_friction"):
                getattr(mi, name)[g] = f[name][k]
            for name in ("body_mass", "body_inertia", "body_ipos"):
                getattr(mi, name)[b] = f[name][k]
        self.params[idx] = np.concatenate(
            [draws["mass"][:, None], draws["com"], draws["friction"][:, None], draws["scale"][:, None],
             shape_one_hot(draws["active"], self.kinds)], axis=1)

    def rest_height(self, draws: dict[str, np.ndarray]) -> np.ndarray:
        """[n] object centre heights (m, world) that put the active shape's base 1 mm above the palm."""
        half_z = np.array([NOMINAL_SIZE[k][1 if k == "cylinder" else 2] for k in self.kinds])
        return PALM_TOP + 0.001 + draws["scale"] * (draws["active"] @ half_z)

    @property
    def extrinsics(self) -> np.ndarray:
        """[M, 11] float32: the episode's object parameters and its current position (HORA's privileged vector);
        [M, 21] with ``object_state_extrinsics`` (then its quaternion, linear and angular velocity)."""
        q = self.sim.qpos
        rel = relative_position(q[:, NJ:NJ + 3], self.consts["palm"])
        return task_extrinsics(self.params, rel, q[:, NJ + 3:NJ + 7], self.object_vel[:, :3], self.object_vel[:, 3:],
                               self.config.object_state_extrinsics).astype(np.float32)

    @property
    def object_angvel_z(self) -> np.ndarray:
        """[M] the object's angular velocity about world z over the last step (rad/s; 0 after a reset)."""
        return self.object_vel[:, 5]

    # ---- reset / step ---------------------------------------------------------------------------
    def _reset_envs(self, idx: np.ndarray) -> None:
        c, r, n = self.config, self._rng, idx.size
        if self.grasps is not None:
            draws = allegro_grasps.draw(self.grasps, r.integers(0, len(self.kinds), size=n), r.random(n))
            qpos, target = draws["qpos"].astype(np.float64), draws["target"].astype(np.float64)
        else:
            draws = self.sample_objects(n)
            pose = self.consts["canonical"] + r.uniform(-c.reset_pose_noise, c.reset_pose_noise, size=(n, NJ))
            pose = np.clip(pose, self.lower, self.upper)
            pos = np.stack([np.full(n, PALM_CENTER[0]), np.full(n, PALM_CENTER[1]), self.rest_height(draws)], axis=1)
            qpos = np.concatenate([pose, pos, yaw_quat(r.uniform(-math.pi, math.pi, size=n))], axis=1)
            target = np.clip(pose + press_offset(c.reset_press), self.lower, self.upper)
        self.set_objects(idx, draws)
        self.sim.set_state(idx, qpos, np.zeros((n, self.model.nv)), ctrl=target)
        self.info["target"][idx] = target
        self.info["obj_pos"][idx] = qpos[:, NJ:NJ + 3]
        self.info["obj_quat"][idx] = qpos[:, NJ + 3:]
        self.object_vel[idx] = 0.0
        self.steps[idx] = 0

    def _state(self):
        q = self.sim.qpos
        adr = self._sensor[f"{self.model.actuator(0).name}_torque"][0]
        return (q[:, :NJ], self.sim.qvel[:, :NJ], q[:, NJ:NJ + 3], q[:, NJ + 3:NJ + 7],
                self.sim.sensordata[:, adr:adr + NJ])

    def _noise(self) -> np.ndarray:
        return self._rng.uniform(-1.0, 1.0, size=(self.num_envs, 2 * NJ)) * self._noise_scale

    def _observe(self) -> tuple[np.ndarray, np.ndarray]:
        jp, jv, pos, quat, tau = self._state()
        zero = np.zeros((self.num_envs, 3))
        return observe(jp, jv, pos, quat, tau, self.info["target"], zero, zero, self.params, self._noise(),
                       self.consts, self.config)

    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        self._reset_envs(np.arange(self.num_envs))
        obs, cobs = self._observe()
        return obs.astype(np.float32), cobs.astype(np.float32)

    def step(self, action: np.ndarray) -> base.StepOut:
        a = np.nan_to_num(np.clip(np.asarray(action, dtype=np.float64).reshape(self.num_envs, NJ), -1.0, 1.0))
        target = next_targets(self.info["target"], a, self.config.action_scale, self.lower, self.upper)
        self.info["target"] = target
        unstable = self.sim.step(target)
        return self._after_physics(unstable)

    def _after_physics(self, unstable: np.ndarray) -> base.StepOut:
        """The rest of ``step`` once ``self.sim`` holds the post-physics state (the parity test calls it)."""
        c = self.config
        jp, jv, pos, quat, tau = self._state()
        next_obs, next_cobs, done, scaled, reward, (linvel, angvel) = step_math(
            jp, jv, pos, quat, tau, self.info, self.params, self._noise(), self.consts, c, self.scales, self.dt)
        self.object_vel = np.concatenate([linvel, angvel], axis=1)
        self.info["obj_pos"] = pos.copy()
        self.info["obj_quat"] = quat.copy()
        self.steps += 1
        out, n_unstable = base.finish_step(next_obs, next_cobs, reward, scaled, done, unstable,
                                           self.steps >= c.episode_length, self._reset_and_observe)
        self.unstable_count += n_unstable
        return out

    def _reset_and_observe(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._reset_envs(idx)
        return self._observe()

    def eval_tracker(self, stepper=None) -> RotationTracker:
        """The evaluation metric's tracker (``play.run_episodes``); ``stepper``: a variant wrapping this task."""
        return RotationTracker(self, stepper)

    def close(self) -> None:
        self.sim.close()


def make(config: AllegroRotateConfig, num_envs: int, seed: int) -> AllegroRotate:
    return AllegroRotate(config, num_envs, seed)
