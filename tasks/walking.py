"""Shared machinery of the gait-phase walking tasks (Go2, G1).

* ``WalkingTask``: the batched CPU task that ``go2_joystick_flat`` and ``g1_walk_flat`` specialise. It owns
  what the two have in common: position servos with a per-joint PD (``position_servos``: Kp on the
  actuator, Kd as joint damping, torque limits taken from the robot's own motor ranges), feet-only
  contacts and the sensors the tasks read (``add_walking_sensors``), a clock-driven gait phase per foot,
  the observation layout (gyro, projected gravity, joint pos - default, joint vel, last action,
  command, gait phase), one velocity command per episode, tilt/height termination, base-velocity
  pushes, per-env domain-randomised models with their parameters in ``extrinsics``, and the
  instability handling shared with Go1 (``base.finish_step``). Subclasses build the model and
  define the reward terms and the domain randomisation.
* The model edits (``robot_spec``, ``position_servos``, ``add_walking_sensors``, ``standing_height``) and
  the per-step math: module-level pure functions on batched arrays written against the shim (the gait
  clock, reward kernels -- several of them Go1's, from ``tasks/go1_math.py`` --, observation,
  ``read_sensors``, ``step_math``), so the MJX variant (``tasks/mjx_walking.py``) runs them on jax arrays.

Like Go1, the walking tasks expose ``command`` and ``base_velocity()`` for the walking metric
(``tasks/walking_metric.py``).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import mujoco
import numpy as np

from tasks import actuation, base, go1_math
from tasks.floating_base import gravity_from_quat, random_base_states
from tasks.model_edits import feet_only_contacts, load_menagerie_spec, set_solver, strip_visuals
from tasks.physics import BatchedSim
from unilab_jax import xp as shim


@dataclasses.dataclass(frozen=True)
class WalkingConfig:
    """Fields every walking task has; each task subclasses it with its own defaults and reward scales."""

    episode_length: int = 1000
    ctrl_dt: float = 0.02
    sim_dt: float = 0.01
    action_scale: float = 0.4
    action_clip: float = 0.0  # > 0: actions are clipped to +-action_clip; 0: not clipped
    integrator: str = "euler"
    solver_iterations: int = 10  # Newton stops early when converged; fewer (<= 4) diverged at sim_dt 0.01
    ls_iterations: int = 10
    # Gait clock: phase_f(t) = (gait_frequency * t + gait_offsets[f]) mod 1; stance while phase < stance_fraction.
    gait_frequency: float = 2.0
    gait_offsets: tuple[float, ...] = (0.0, 0.5, 0.5, 0.0)
    stance_fraction: float = 0.5
    # Observation noise: U(-1, 1) * noise_level * scale.
    noise_level: float = 1.0
    noise_gyro: float = 0.0
    noise_gravity: float = 0.0
    noise_joint_pos: float = 0.01
    noise_joint_vel: float = 0.1
    # Commands (vx, vy, yaw rate) ~ U(command_low, command_high), one per episode.
    command_low: tuple[float, float, float] = (-0.6, -0.4, -0.8)
    command_high: tuple[float, float, float] = (1.0, 0.4, 0.8)
    # Reset and termination.
    reset_xy: float = 0.5
    reset_yaw: float = math.pi
    reset_base_vel: float = 0.5
    max_tilt_deg: float = 60.0
    min_base_height: float = 0.0  # > 0: terminate when the base is lower
    # Reward kernels.
    tracking_sigma: float = 0.4
    base_height_target: float = 0.3
    swing_height_target: float = 0.1
    swing_height_sigma: float = 0.01
    # Pushes: every push_interval_s of episode time the base velocity gets + U(+-push_vel) (0: none).
    push_interval_s: float = 15.0
    push_vel: tuple[float, float, float] = (1.0, 1.0, 0.5)
    domain_randomization: bool = True
    # Actuation randomisation (off: (1, 1) and (0, 0); the rough tasks turn both on): each motor's PD torque (Kp
    # and Kd) x U(dr_motor_strength), per env and motor; the motors get the action of U{dr_action_delay} control
    # steps ago, per env (``tasks/actuation.py``).
    dr_motor_strength: tuple[float, float] = (1.0, 1.0)
    dr_action_delay: tuple[int, int] = (0, 0)
    physics_engine: str = "rollout"  # "rollout" or "step" (tasks/physics.py)
    sensors_every_substep: bool = False


# --------------------------------------------------------------------------------------------------
# Model helpers (MjSpec edits)
# --------------------------------------------------------------------------------------------------
def robot_spec(robot: str, config: Any, find_feet: Callable[[mujoco.MjSpec], list]) -> tuple[mujoco.MjSpec, list]:
    """A Menagerie robot's scene with the edits every walking task makes: the config's solver, no visual-only
    assets, and contacts between the feet (``find_feet(spec)``, once the visuals are gone) and the floor
    only, with condim 3 on the feet. Returns (spec, feet)."""
    spec = load_menagerie_spec(robot)
    set_solver(spec, config)
    strip_visuals(spec)
    feet = find_feet(spec)
    feet_only_contacts(spec, feet)
    for g in feet:
        g.condim = 3
    return spec, feet


def position_servos(spec: mujoco.MjSpec, kp: Sequence[float], kd: Sequence[float]) -> np.ndarray:
    """Turns the robot's torque motors into PD position servos; returns their torque limits [nu].

    Actuator i (spec order) becomes ``tau = clip(kp[i] * (ctrl - q), +-limit)`` with ``limit`` the motor's
    own ``ctrlrange`` (its torque range); the derivative part ``-kd[i] * qdot`` is the joint's damping, so
    the Euler integrator treats it implicitly (stable at the tasks' 5-10 ms steps) -- as UniLab sets Kd.
    ``ctrl`` (the joint target) is left unlimited.
    """
    limits = []
    for i, a in enumerate(spec.actuators):
        limit = float(np.max(np.abs(a.ctrlrange)))
        if limit <= 0.0:
            raise ValueError(f"actuator {a.name!r} has no torque range to take the limit from")
        limits.append(limit)
        a.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        a.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        a.gainprm[0] = kp[i]
        a.biasprm[0], a.biasprm[1], a.biasprm[2] = 0.0, -kp[i], 0.0
        a.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        a.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        a.forcerange = [-limit, limit]
        joint = spec.joint(a.target)
        damping = np.zeros_like(np.asarray(joint.damping, dtype=np.float64))
        damping.flat[0] = kd[i]  # MuJoCo 4's damping is (linear, v|v|, v^3) coefficients: linear only
        joint.damping = damping if damping.ndim else float(kd[i])
    return np.array(limits)


def add_walking_sensors(spec: mujoco.MjSpec, imu_site: str, feet: Sequence[tuple[str, Any, str, Any, str]],
                        floor: str = "floor") -> None:
    """The sensors ``WalkingTask`` reads: gyro / local_linvel / orientation at ``imu_site``; per foot
    ``(name, pos objtype, pos objname, contact objtype, contact objname)``: ``{name}_pos``,
    ``{name}_vel`` (world frame) and ``{name}_contact`` (1 while touching ``floor``); and
    ``{actuator}_force`` per actuator."""
    S, Ob = mujoco.mjtSensor, mujoco.mjtObj

    def add(name, type_, objtype=Ob.mjOBJ_SITE, objname=imu_site, **kw):
        spec.add_sensor(name=name, type=type_, objtype=objtype, objname=objname, **kw)

    add("gyro", S.mjSENS_GYRO)
    add("local_linvel", S.mjSENS_VELOCIMETER)
    add("orientation", S.mjSENS_FRAMEQUAT)
    for name, pos_type, pos_name, contact_type, contact_name in feet:
        add(f"{name}_pos", S.mjSENS_FRAMEPOS, pos_type, pos_name)
        add(f"{name}_vel", S.mjSENS_FRAMELINVEL, pos_type, pos_name)
        # data="found", reduce="mindist", num=1: 1 if the foot touches the floor.
        add(f"{name}_contact", S.mjSENS_CONTACT, contact_type, contact_name, reftype=Ob.mjOBJ_GEOM,
            refname=floor, intprm=[1, 1, 1])
    for a in spec.actuators:
        add(f"{a.name}_force", S.mjSENS_ACTUATORFRC, Ob.mjOBJ_ACTUATOR, a.name)


def standing_height(model: mujoco.MjModel, qpos: np.ndarray, foot_geoms: Sequence[int]) -> float:
    """Base height at which the lowest point of the (sphere) ``foot_geoms`` touches z = 0 in pose ``qpos``."""
    d = mujoco.MjData(model)
    d.qpos[:] = qpos
    d.qpos[2] = 0.0
    mujoco.mj_kinematics(model, d)
    ids = np.asarray(foot_geoms)
    return float(-np.min(d.geom_xpos[ids, 2] - model.geom_size[ids, 0]))


# --------------------------------------------------------------------------------------------------
# Task math on the shim. Shapes: [M, ...] batched over envs; a feet axis F in the task's foot order.
# --------------------------------------------------------------------------------------------------
def gait_phase(t, frequency: float, offsets):
    """[M, F] phase in [0, 1) of each foot at episode time ``t [M]``: (frequency * t + offset) mod 1."""
    xp = shim.namespace(t)
    return xp.remainder(t[:, None] * frequency + offsets, 1.0)


def phase_features(phase):
    """[M, 2K] (sin 2 pi phase_k, cos 2 pi phase_k) interleaved, for phases ``[M, K]``."""
    xp = shim.namespace(phase)
    ang = 2.0 * math.pi * phase
    return xp.reshape(xp.stack([xp.sin(ang), xp.cos(ang)], axis=-1), (phase.shape[0], 2 * phase.shape[1]))


def stance_mask(phase, stance_fraction: float):
    """[M, F] bool: the gait clock puts the foot in stance (phase < stance_fraction)."""
    return phase < stance_fraction


def cost_base_height(base_z, target: float):
    return shim.namespace(base_z).square(base_z - target)


def cost_pose_l1(joint_pos, default_pose, weight):
    """Weighted L1 deviation from the default pose, sum_j w_j |q_j - q0_j|."""
    xp = shim.namespace(joint_pos)
    return xp.sum(xp.abs(joint_pos - default_pose) * weight, axis=-1)


def reward_contact_phase(contact, stance):
    """Number of feet whose contact matches the gait clock (touching in stance, lifted in swing)."""
    xp = shim.namespace(contact)
    return xp.sum(xp.where(contact == stance, 1.0, 0.0), axis=-1)


def reward_swing_height(feet_h, stance, target: float, sigma: float):
    """sum over swinging feet of exp(-(h - target)^2 / sigma); ``feet_h [M, F]`` sole heights."""
    xp = shim.namespace(feet_h)
    k = xp.exp(-xp.square(feet_h - target) / sigma)
    return xp.sum(k * xp.astype(~stance, k.dtype), axis=-1)


def reward_terms(names: Sequence[str], *, command, local_linvel, gyro, base_z, joint_pos, default_pose, action,
                 last_act, contact, stance, feet_h, tracking_sigma: float, base_height_target: float,
                 swing_height_target: float, swing_height_sigma: float, pose_weight=None, gravity=None,
                 actuator_force=None, feet_vel=None, done=None):
    """The walking tasks' unscaled reward terms ``names``, each [M], in that order (a task asks only for
    terms whose inputs it passes). ``pose_weight`` None: every joint weighs 1."""
    xp = shim.namespace(joint_pos)
    terms = {
        "tracking_lin_vel": lambda: go1_math.reward_tracking_lin_vel(command, local_linvel, tracking_sigma),
        "tracking_ang_vel": lambda: go1_math.reward_tracking_ang_vel(command, gyro, tracking_sigma),
        "lin_vel_z": lambda: go1_math.cost_lin_vel_z(local_linvel),
        "ang_vel_xy": lambda: go1_math.cost_ang_vel_xy(gyro),
        "orientation": lambda: go1_math.cost_orientation(gravity),
        "base_height": lambda: cost_base_height(base_z, base_height_target),
        "action_rate": lambda: go1_math.cost_action_rate(action, last_act),
        "torques": lambda: go1_math.cost_torques(actuator_force),
        "feet_contact_phase": lambda: reward_contact_phase(contact, stance),
        "feet_swing_height": lambda: reward_swing_height(feet_h, stance, swing_height_target, swing_height_sigma),
        "feet_slip": lambda: go1_math.cost_feet_slip(command, feet_vel, contact),
        "pose": lambda: cost_pose_l1(joint_pos, default_pose,
                                     xp.ones_like(default_pose) if pose_weight is None else pose_weight),
        "termination": lambda: xp.astype(done, joint_pos.dtype),
    }
    return {name: terms[name]() for name in names}


def terminated(gravity, base_z, max_tilt_deg: float, min_base_height: float):
    """[M] bool: tilt (angle between body z and world z) above ``max_tilt_deg``, or base below the minimum.

    ``gravity`` is the projected gravity (body frame), so cos(tilt) = -gravity_z.
    """
    return (-gravity[:, 2] < math.cos(math.radians(max_tilt_deg))) | (base_z < min_base_height)


def actor_obs(gyro, gravity, joint_pos, joint_vel, last_act, command, phase_feat, default_pose, noise):
    """Actor observation [gyro 3, gravity 3, q - q0 n, qdot n, last action, command 3, phase features].

    ``noise [M, 6 + 2n]`` (U(-1, 1) draws times the scales) is added to gyro, gravity, q and qdot.
    """
    xp = shim.namespace(gyro, gravity, joint_pos, joint_vel, last_act, command, phase_feat, noise)
    n = joint_pos.shape[1]
    noisy = xp.concat([gyro, gravity, joint_pos - default_pose, joint_vel], axis=-1) + noise
    return xp.concat([noisy[:, : 6 + 2 * n], last_act, command, phase_feat], axis=-1)


def read_sensors(sensordata, qpos, qvel, layout: Mapping[str, Any]) -> dict:
    """The physical readings the observation and rewards use at one state, from batched ``sensordata
    [M, nsensordata]``, ``qpos [M, nq]`` and ``qvel [M, nv]``.

    ``layout`` (``WalkingTask.sensor_layout()``) holds the sensor addresses and foot / joint indices.
    Returns gyro, local_linvel, orientation, gravity, feet_h / feet_vel / contact ([M, F], foot order),
    actuator_force, base_z, joint_pos / joint_vel (policy joints). The task adds the gait clock's
    ``phase`` and ``stance`` ([M, F]) and the episode state ``command`` and ``last_act``.
    """
    xp = shim.namespace(sensordata)
    index = layout["index"]

    def get(name):
        adr, dim = index[name]
        return sensordata[:, adr : adr + dim]

    feet = layout["feet"]
    s = {k: get(k) for k in ("gyro", "local_linvel", "orientation")}
    s["gravity"] = gravity_from_quat(s["orientation"])
    s["feet_h"] = xp.stack([get(f"{f}_pos")[:, 2] for f in feet], axis=1) - layout["sole_offset"]
    s["feet_vel"] = xp.stack([get(f"{f}_vel") for f in feet], axis=1)
    s["contact"] = xp.stack([get(f"{f}_contact")[:, 0] for f in feet], axis=1) > 0
    adr = layout["force_adr"]
    s["actuator_force"] = sensordata[:, adr : adr + layout["nu"]]
    s["base_z"] = qpos[:, 2]
    s["joint_pos"] = qpos[:, layout["qadr"]]
    s["joint_vel"] = qvel[:, layout["vadr"]]
    return s


def observe(s, last_act, noise, default_pose, phase_groups, critic_extra: Callable):
    """(actor obs, critic obs) from ``s`` (``read_sensors`` plus ``phase`` and ``command``): the actor
    observation with ``last_act``, then the critic's clean local linear velocity and ``critic_extra(s)``."""
    xp = shim.namespace(s["gyro"])
    obs = actor_obs(s["gyro"], s["gravity"], s["joint_pos"], s["joint_vel"], last_act, s["command"],
                    phase_features(s["phase"][:, phase_groups]), default_pose, noise)
    cobs = xp.concat([obs, s["local_linvel"], critic_extra(s)], axis=1)
    return obs, cobs


def step_math(s, action, noise, default_pose, phase_groups, config: Any, scales: Mapping[str, float], dt: float,
              reward_terms: Callable, critic_extra: Callable):
    """Everything a walking step computes after the physics, on the shim (numpy for the CPU task, jax for
    ``tasks/mjx_walking.py``).

    ``s``: ``read_sensors`` at the post-step state plus the gait clock's ``phase`` / ``stance`` and the
    per-env episode state ``command [M, 3]`` and ``last_act [M, n]`` (the previous action); ``action
    [M, n]``: the action just applied; ``noise``: the observation noise (draws times scales).
    ``reward_terms(s, action, done) -> {name: [M]}`` and ``critic_extra(s) -> [M, k]`` are the task's hooks.
    Returns (next_obs, next_critic_obs, done [M] bool, scaled terms {name: dt * scale * term}, reward [M]);
    the observation shows ``action`` as the last action.
    """
    done = terminated(s["gravity"], s["base_z"], config.max_tilt_deg, config.min_base_height)
    scaled = go1_math.scale_terms(reward_terms(s, action, done), scales, dt)
    xp = shim.namespace(s["gyro"])
    reward = xp.sum(xp.stack(list(scaled.values())), axis=0)
    next_obs, next_cobs = observe(s, action, noise, default_pose, phase_groups, critic_extra)
    return next_obs, next_cobs, done, scaled, reward


# --------------------------------------------------------------------------------------------------
# The numpy task
# --------------------------------------------------------------------------------------------------
class WalkingTask(base.Task):
    """Batched gait-phase walking task. Subclasses define (class attributes and hooks):

    ``NAME``, ``REWARD_TERMS``; ``FEET`` (sensor name prefixes, the foot order of ``gait_offsets``);
    ``build_spec(config) -> MjSpec`` (robot, servos, contacts, ``add_walking_sensors``);
    ``home_qpos(model) -> [nq]`` (reset pose; its actuated joints are the default pose);
    ``foot_geoms(model)`` (sphere geoms for the standing height) and ``sole_offsets(model) [F]`` (foot
    sensor height above the sole); ``policy_actuators(model)`` (indices the action drives; the rest hold
    their default); the ``REWARD_TERMS`` come from ``walking.reward_terms`` (weighted by ``pose_weight``);
    ``critic_extra(s)``; ``sample_dr()`` and ``randomize_model(model, i)`` for domain randomisation (the
    actuation's, ``dr_motor_strength`` / ``dr_action_delay``, is this class's). What a rough-terrain subclass
    overrides (``tasks/rough.py``'s ``RoughTask``): ``base_states(idx)``, ``extend_obs``, ``at_limit``.
    """

    NAME: str = ""
    REWARD_TERMS: tuple[str, ...] = ()
    FEET: tuple[str, ...] = ()
    pose_weight: Any = None  # [n] per-joint weights of the pose term (None: 1 each)

    def __init__(self, config: WalkingConfig, num_envs: int, seed: int):
        super().__init__(config, num_envs, seed)
        c = config
        nsub = round(c.ctrl_dt / c.sim_dt)
        if nsub < 1 or abs(nsub * c.sim_dt - c.ctrl_dt) > 1e-9:
            raise ValueError(f"ctrl_dt {c.ctrl_dt} must be a multiple of sim_dt {c.sim_dt}")
        if len(c.gait_offsets) != len(self.FEET):
            raise ValueError(f"gait_offsets needs one offset per foot {self.FEET}, got {c.gait_offsets}")
        self.dt = c.ctrl_dt
        self.model = self.build_spec(c).compile()
        m, M = self.model, self.num_envs
        self._rng = np.random.Generator(np.random.Philox(self.seed))
        # Joints: the actuated ones (servo targets) and the subset the policy drives.
        jnt = m.actuator_trnid[:, 0]
        self._act_qadr, self._act_vadr = m.jnt_qposadr[jnt], m.jnt_dofadr[jnt]
        self.policy_idx = np.asarray(self.policy_actuators(m), dtype=np.int64)
        self._qadr, self._vadr = self._act_qadr[self.policy_idx], self._act_vadr[self.policy_idx]
        self.init_qpos = np.array(self.home_qpos(m), dtype=np.float64)
        self.init_qpos[2] = standing_height(m, self.init_qpos, self.foot_geoms(m))
        self.sole_offset = np.asarray(self.sole_offsets(m), dtype=np.float64)
        self.default_ctrl = self.init_qpos[self._act_qadr].copy()
        self.default_pose = self.default_ctrl[self.policy_idx].copy()
        self.gait_offsets = np.array(c.gait_offsets, dtype=np.float64)
        _, first = np.unique(self.gait_offsets, return_index=True)
        self.phase_groups = np.sort(first)  # one foot per distinct phase (their sin/cos is observed)
        self._sensor = {m.sensor(i).name: (m.sensor_adr[i], m.sensor_dim[i]) for i in range(m.nsensor)}
        self._force_adr = self._sensor[f"{m.actuator(0).name}_force"][0]
        n = self.policy_idx.size
        self._noise_scale = c.noise_level * np.concatenate(
            [np.full(3, c.noise_gyro), np.full(3, c.noise_gravity), np.full(n, c.noise_joint_pos),
             np.full(n, c.noise_joint_vel)]
        )
        self.scales = base.reward_scales(c, self.REWARD_TERMS)
        self._cmd_low, self._cmd_high = np.array(c.command_low), np.array(c.command_high)
        self._push_every = round(c.push_interval_s / self.dt) if c.push_interval_s > 0 else 0
        # Domain randomisation: per-env parameters (self.dr, flattened in self.extrinsics) and models; the
        # actuation's drawn after the task's own, and only when on (the flat tasks' draws stay as they were).
        self.dr = self.sample_dr()
        lo, hi = c.dr_motor_strength
        if c.domain_randomization and (lo, hi) != (1.0, 1.0):
            self.dr["motor_strength"] = self._rng.uniform(lo, hi, size=(M, m.nu))
        delays = actuation.sample_delays(self._rng, c.dr_action_delay, M) if c.domain_randomization else None
        if delays is not None:
            self.dr["action_delay"] = delays[:, None].astype(np.float64)
        self.delay = actuation.ActionDelay(np.zeros(M) if delays is None else delays, c.dr_action_delay[1], n)
        self.extrinsics_layout = tuple((k, self.dr[k].shape[1]) for k in sorted(self.dr))
        self.extrinsics = np.concatenate([self.dr[k] for k in sorted(self.dr)], axis=1).astype(np.float32)
        models = None
        if c.domain_randomization:
            models = []
            for i in range(M):
                mi = copy.copy(m)
                self.randomize_model(mi, i)
                if "motor_strength" in self.dr:
                    strength = self.dr["motor_strength"][i]
                    mi.actuator_gainprm[:, 0] *= strength
                    mi.actuator_biasprm[:, 1] *= strength
                    mi.dof_damping[self._act_vadr] *= strength
                models.append(mi)
        self.sim = BatchedSim(m, M, nsub, engine=c.physics_engine, models=models,
                              sensors_every_substep=c.sensors_every_substep)
        # Per-env episode state.
        self.command = np.zeros((M, 3))
        self.last_act = np.zeros((M, n))
        self.steps = np.zeros(M, dtype=np.int64)
        self.unstable_count = 0
        self.push_count = 0
        obs_dim = 6 + 3 * n + 3 + 2 * self.phase_groups.size
        extra = self.critic_extra(self._sensors()).shape[1]
        self.spec = base.TaskSpec(
            name=self.NAME, obs_dim=obs_dim, critic_obs_dim=obs_dim + 3 + extra, action_dim=n,
            episode_length=c.episode_length, ctrl_dt=c.ctrl_dt, reward_terms=self.REWARD_TERMS,
            privileged_dim=self.extrinsics.shape[1],
        )

    # ---- hooks ----------------------------------------------------------------------------------
    def build_spec(self, config) -> mujoco.MjSpec:
        raise NotImplementedError

    def home_qpos(self, model: mujoco.MjModel) -> np.ndarray:
        raise NotImplementedError

    def foot_geoms(self, model: mujoco.MjModel) -> Sequence[int]:
        raise NotImplementedError

    def sole_offsets(self, model: mujoco.MjModel) -> Sequence[float]:
        """[F] height of each ``{foot}_pos`` sensor above the foot's sole when it stands on the floor."""
        raise NotImplementedError

    def policy_actuators(self, model: mujoco.MjModel) -> Sequence[int]:
        return range(model.nu)

    def reward_terms(self, s: Mapping[str, Any], action: Any, done: Any) -> dict[str, Any]:
        """Unscaled terms {name: [M]} in ``REWARD_TERMS`` order from ``s`` (``read_sensors`` plus ``command``
        and ``last_act``, the previous action). Shim-written and reading nothing per-env from ``self`` (only
        constants: config, default pose, ``pose_weight``), so the MJX variant calls it on jax arrays."""
        c = self.config
        return reward_terms(
            self.REWARD_TERMS, command=s["command"], local_linvel=s["local_linvel"], gyro=s["gyro"],
            base_z=s["base_z"], joint_pos=s["joint_pos"], default_pose=self.default_pose, action=action,
            last_act=s["last_act"], contact=s["contact"], stance=s["stance"], feet_h=s["feet_h"],
            tracking_sigma=c.tracking_sigma, base_height_target=c.base_height_target,
            swing_height_target=c.swing_height_target, swing_height_sigma=c.swing_height_sigma,
            pose_weight=self.pose_weight, gravity=s["gravity"], actuator_force=s.get("actuator_force"),
            feet_vel=s.get("feet_vel"), done=done)

    def critic_extra(self, s: Mapping[str, Any]) -> Any:
        """[M, k] privileged signals appended to the critic observation after the local linear velocity
        (shim-written, like ``reward_terms``)."""
        xp = shim.namespace(s["base_z"])
        return xp.zeros((s["base_z"].shape[0], 0), dtype=s["base_z"].dtype)

    def sample_dr(self) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def randomize_model(self, model: mujoco.MjModel, i: int) -> None:
        raise NotImplementedError

    # ---- helpers --------------------------------------------------------------------------------
    def _s(self, name: str) -> np.ndarray:
        adr, dim = self._sensor[name]
        return self.sim.sensordata[:, adr : adr + dim]

    def sensor_layout(self) -> dict[str, Any]:
        """What ``read_sensors`` needs besides the arrays: sensor addresses, foot and joint indices."""
        return {"index": self._sensor, "feet": self.FEET, "sole_offset": self.sole_offset,
                "force_adr": self._force_adr, "nu": self.model.nu, "qadr": self._qadr, "vadr": self._vadr}

    def _sensors(self) -> dict[str, np.ndarray]:
        """Everything the observation and rewards read, at the current state (with the episode state)."""
        c = self.config
        s = read_sensors(self.sim.sensordata, self.sim.qpos, self.sim.qvel, self.sensor_layout())
        s["phase"] = gait_phase(self.steps * self.dt, c.gait_frequency, self.gait_offsets)
        s["stance"] = stance_mask(s["phase"], c.stance_fraction)
        s["command"], s["last_act"] = self.command, self.last_act
        return s

    def _noise(self) -> np.ndarray:
        return self._rng.uniform(-1.0, 1.0, size=(self.num_envs, self._noise_scale.size)) * self._noise_scale

    def _observe(self, s: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        return self.extend_obs(*observe(s, self.last_act, self._noise(), self.default_pose, self.phase_groups,
                                        self.critic_extra))

    def _ctrl(self, action: np.ndarray) -> np.ndarray:
        ctrl = np.tile(self.default_ctrl, (self.num_envs, 1))
        ctrl[:, self.policy_idx] += self.config.action_scale * action
        return ctrl

    def base_states(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(qpos [n, nq], qvel [n, nv]) of new episodes of envs ``idx`` (the rough tasks move them onto cells)."""
        c = self.config
        return random_base_states(self.init_qpos, self.model.nv, idx.size, self._rng, c.reset_xy, c.reset_yaw,
                                  c.reset_base_vel)

    def extend_obs(self, obs: np.ndarray, critic_obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(obs, critic_obs) of the current state with what a subclass appends (the rough tasks' height scan)."""
        return obs, critic_obs

    def at_limit(self) -> np.ndarray:
        """[M] bool: episodes truncated after this step (the time limit; the rough tasks add leaving the map)."""
        return self.steps >= self.config.episode_length

    def _reset_envs(self, idx: np.ndarray) -> None:
        r, n = self._rng, idx.size
        qpos, qvel = self.base_states(idx)
        self.sim.set_state(idx, qpos, qvel, ctrl=np.tile(self.default_ctrl, (n, 1)))
        self.delay.reset(idx)
        self.command[idx] = r.uniform(self._cmd_low, self._cmd_high, size=(n, 3))
        self.last_act[idx] = 0.0
        self.steps[idx] = 0

    def _reset_and_observe(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._reset_envs(idx)
        return self._observe(self._sensors())

    def _push(self, done: np.ndarray) -> None:
        if not self._push_every:
            return
        idx = np.flatnonzero((self.steps % self._push_every == 0) & ~done)
        if idx.size:
            dq = np.zeros((idx.size, self.model.nv))
            lim = np.array(self.config.push_vel)
            dq[:, 0:3] = self._rng.uniform(-lim, lim, size=(idx.size, 3))
            self.sim.add_velocity(idx, dq)
            self.push_count += int(idx.size)

    # ---- API ------------------------------------------------------------------------------------
    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        obs, cobs = self._reset_and_observe(np.arange(self.num_envs))
        return obs.astype(np.float32), cobs.astype(np.float32)

    def step(self, action: np.ndarray) -> base.StepOut:
        c = self.config
        a = np.nan_to_num(np.asarray(action, dtype=np.float64).reshape(self.num_envs, -1), nan=0.0)
        if c.action_clip > 0:
            a = np.clip(a, -c.action_clip, c.action_clip)
        return self._after_physics(a, self.sim.step(self._ctrl(self.delay.apply(a))))

    def _after_physics(self, a: np.ndarray, unstable: np.ndarray) -> base.StepOut:
        """The rest of ``step`` once ``self.sim`` holds the post-physics state and sensors (the MJX parity
        tests call it on a state set with ``sim.set_state``)."""
        c = self.config
        self.steps += 1
        next_obs, next_cobs, done, scaled, reward = step_math(
            self._sensors(), a, self._noise(), self.default_pose, self.phase_groups, c, self.scales, self.dt,
            self.reward_terms, self.critic_extra)
        next_obs, next_cobs = self.extend_obs(next_obs, next_cobs)
        self.last_act = a  # the observation shows the action just applied
        self._push(done)
        out, n_unstable = base.finish_step(next_obs, next_cobs, reward, scaled, done, unstable,
                                           self.at_limit(), self._reset_and_observe)
        self.unstable_count += n_unstable
        return out

    def base_velocity(self) -> np.ndarray:
        """[M, 3] measured body-frame (vx, vy) and yaw rate: what ``command`` asks for (walking metric)."""
        return np.concatenate([self._s("local_linvel")[:, :2], self._s("gyro")[:, 2:3]], axis=1)

    def close(self) -> None:
        self.sim.close()
