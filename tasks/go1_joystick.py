"""``go1_joystick_flat``: Unitree Go1 velocity tracking on flat ground, parity with MuJoCo Playground.

Mirrors Playground's ``Go1JoystickFlatTerrain`` (``mujoco_playground/_src/locomotion/go1/joystick.py``
with ``scene_mjx_feetonly_flat_terrain.xml`` and ``randomize.py``), rebuilt on the CPU:

* Model: Menagerie's ``unitree_go1`` scene loaded through ``mujoco_menagerie`` and edited with
  ``mujoco.MjSpec`` (never a copied XML): sim_dt 0.004 (5 substeps of ctrl_dt 0.02), Euler, 1
  solver iteration / 5 line-search iterations, pyramidal cone; feet-only contacts (every geom but
  the four foot spheres gets contype = conaffinity = 0; feet collide with the floor only; the floor
  has priority so its friction/condim 3 apply); no joint damping; position actuators
  ``target = default pose + 0.5 * action`` with Kp 35, Kd 0.5 and Menagerie's force limits; the IMU
  site at Playground's position; Playground's flat-terrain ``home`` keyframe (0.278 m, hip
  abduction +-0.1); sensors (gyro, velocimeter, accelerometer, framezaxis, framelinvel /
  frameangvel, framequat, per-foot framepos / framelinvel / contact "found", per-actuator
  actuatorfrc). Visual meshes and textures are stripped (no physical effect; keeps the per-env
  model copies used for domain randomisation ~50 kB each instead of ~40 MB).
* Observation (48, noisy): local linear velocity 3, gyro 3, gravity in the IMU frame 3, joint
  angles - default 12, joint velocities 12, last action 12, command 3. Uniform noise
  ``U(-1, 1) * level * scale`` (joint pos 0.03, joint vel 1.5, gyro 0.2, gravity 0.05, linvel 0.1).
  As in Playground the observation is built before the step's bookkeeping, so its "last action"
  is the action of the *previous* control step and its command the one before resampling.
* Critic observation (123): the actor observation, then clean gyro 3, accelerometer 3, gravity 3,
  local linvel 3, global angvel 3, joint angles - default 12, joint velocities 12, actuator forces
  12, last foot contacts 4, foot velocities 12, feet air time 4, perturbation force 3 and
  perturbation flag 1 (both always 0: Playground's perturbations are disabled by default).
* Reward per step = clip(ctrl_dt * sum(scale * term), 0, inf) over the 16 Playground terms;
  ``StepOut.reward_terms`` holds each ``ctrl_dt * scale * term`` (their sum is the pre-clip reward).
* Commands ``U(-a, a)`` with ``a = (1.5, 0.8, 1.2)`` at reset; after an exponential time of mean
  5 s each axis is, with probability 1/2, replaced by a new uniform value that is zeroed with
  probability ``1 - b`` (``b = (0.9, 0.25, 0.5)``), Playground's ``sample_command``.
* Reset: home pose, xy +-0.5 m, yaw +-3.14, base linear/angular velocity U(+-0.5).
  Termination: torso up-vector z < 0. Time limit 1000 steps (truncation).
* Domain randomisation (sampled once per env at construction, like brax's DR wrapper): floor
  friction U(0.4, 1.0), joint frictionloss x U(0.9, 1.1), armature x U(1.0, 1.05), torso COM
  + U(+-0.05) m, all body masses x U(0.9, 1.1), torso mass + U(+-1) kg, default pose + U(+-0.05);
  optionally motor strength (``dr_motor_strength``: each motor's PD torque, i.e. Kp and Kd, scaled by a
  per-motor factor) and action latency (``dr_action_delay``: the motors get the action of 0-k control steps ago,
  per env, ``tasks/actuation.py``); both off by default, which keeps Playground parity and the random stream
  unchanged (``go1_joystick_rough`` turns them on).
  The parameters live in numpy arrays (``self.dr``) and, flattened, in ``self.extrinsics``
  ``[M, privileged_dim]`` float32 for teacher/student methods (``self.extrinsics_layout`` names
  the columns: armature_scale 12, com_offset 3, default_pose_offset 12, floor_friction 1,
  frictionloss_scale 12, mass_scale 13 (bodies 1..13), motor_strength 12, torso_mass_delta 1; action_delay 1
  first when the latency is on).
  Deviation: Playground jitters ``model.qpos0``, which no Go1 dynamics reads (a no-op). Here the
  offset is also added to the motor targets (a joint-calibration error; observations and rewards
  keep the nominal default pose), so the parameter means something to a teacher/student method;
  ``dr_pose_offset_on_targets=False`` restores the no-op.
* Unstable envs (MuJoCo divergence warnings or a non-finite state/observation) are truncated
  and reset; their outputs are zeroed rather than NaN and counted in ``self.unstable_count``.
* For velocity-tracking metrics (``tasks.walking_metric.walking_metric``): ``self.command [M, 3]`` is the
  command in force and ``self.base_velocity() [M, 3]`` the measured body-frame (vx, vy, yaw rate).

Other choices: ``integrator`` follows DESIGN.md (Euler; with no joint damping Euler is plain
explicit Euler); Playground's newest XML says ``implicitfast``, available as an override. With
``sensors_every_substep=False`` the physics wrapper may skip sensor evaluation on the first 4 of
the 5 substeps where that measured faster (see ``tasks/physics.py``); Playground only reads the
sensors after the last one, and the dynamics are unchanged (bit-identical, tested).

This module holds the configuration, the model (``build_spec``) and the numpy task. The observation/reward
math is module-level pure functions on batched arrays written against the shim, in ``tasks/go1_math.py``
(``read_sensors``, ``step_math``: everything a step computes after the physics, ``sample_command``), with
the reset poses from ``tasks/floating_base.py`` (``place_base``): what ``tasks/mjx_go1.py`` runs on jax
arrays, so the MJX variant is this MDP. The Menagerie loading and MjSpec edits the tasks share are in
``tasks/model_edits.py``; the end of a step (instability masking, auto-reset) is ``base.finish_step``.
"""

from __future__ import annotations

import copy
import dataclasses

import mujoco
import numpy as np

from tasks import actuation, base
from tasks.floating_base import random_base_states
from tasks.go1_math import (
    CRITIC_OBS_DIM,
    FEET,
    OBS_DIM,
    POSE_WEIGHT,
    REWARD_SCALES,
    REWARD_TERMS,
    noise_scales,
    observe,
    read_sensors,
    sample_command,
    step_math,
)
from tasks.model_edits import feet_only_contacts, load_menagerie_spec, sensor_index, set_solver, strip_visuals
from tasks.physics import BatchedSim

# Playground's flat-terrain "home" keyframe (scene_mjx_feetonly_flat_terrain.xml).
HOME_QPOS = (0.0, 0.0, 0.278, 1.0, 0.0, 0.0, 0.0) + (0.1, 0.9, -1.8, -0.1, 0.9, -1.8) * 2
IMU_POS = (-0.01592, -0.06659, -0.00617)  # Playground's IMU site (Menagerie has it at the origin)


@base.with_reward_scales(REWARD_SCALES)
@dataclasses.dataclass(frozen=True)
class Go1JoystickConfig:
    """Configuration of ``go1_joystick_flat`` (Playground defaults; override any field by name)."""

    episode_length: int = 1000
    ctrl_dt: float = 0.02
    sim_dt: float = 0.004
    kp: float = 35.0
    kd: float = 0.5
    action_scale: float = 0.5
    solver_iterations: int = 1
    ls_iterations: int = 5
    soft_joint_pos_limit_factor: float = 0.95
    # Observation noise: U(-1, 1) * noise_level * scale.
    noise_level: float = 1.0
    noise_joint_pos: float = 0.03
    noise_joint_vel: float = 1.5
    noise_gyro: float = 0.2
    noise_gravity: float = 0.05
    noise_linvel: float = 0.1
    # Reward.
    tracking_sigma: float = 0.25
    max_foot_height: float = 0.1
    # Commands (vx, vy, yaw rate).
    command_a: tuple[float, float, float] = (1.5, 0.8, 1.2)
    command_b: tuple[float, float, float] = (0.9, 0.25, 0.5)
    command_resample_mean_s: float = 5.0
    # Reset.
    reset_xy: float = 0.5
    reset_yaw: float = 3.14
    reset_base_vel: float = 0.5
    # Domain randomisation (sampled once per env).
    domain_randomization: bool = True
    dr_floor_friction: tuple[float, float] = (0.4, 1.0)
    dr_frictionloss_scale: tuple[float, float] = (0.9, 1.1)
    dr_armature_scale: tuple[float, float] = (1.0, 1.05)
    dr_com_offset: float = 0.05
    dr_link_mass_scale: tuple[float, float] = (0.9, 1.1)
    dr_torso_mass_delta: float = 1.0
    dr_default_pose_offset: float = 0.05
    dr_motor_strength: tuple[float, float] = (1.0, 1.0)  # per-motor PD torque scale; (1, 1): off (parity)
    dr_action_delay: tuple[int, int] = (0, 0)  # per-env action latency, control steps (tasks/actuation.py); off
    physics_engine: str = "rollout"  # "rollout" or "step" (tasks/physics.py)
    sensors_every_substep: bool = False  # False: skip sensors on inner substeps where faster
    integrator: str = "euler"  # DESIGN.md: Euler; Playground's newest XML uses "implicitfast"
    dr_pose_offset_on_targets: bool = True  # see the module docstring


def default_config() -> Go1JoystickConfig:
    return Go1JoystickConfig()


def reward_scales(config: Go1JoystickConfig) -> dict[str, float]:
    return base.reward_scales(config, REWARD_TERMS)


# --------------------------------------------------------------------------------------------------
# Model
# --------------------------------------------------------------------------------------------------
def load_go1_spec() -> mujoco.MjSpec:
    """Menagerie's Go1 scene as an editable MjSpec (``MENAGERIE_ROOT`` for offline copies)."""
    return load_menagerie_spec("unitree_go1")


def build_spec(config: Go1JoystickConfig) -> mujoco.MjSpec:
    """Playground's feet-only Go1 flat-terrain model, made from Menagerie's scene with MjSpec edits."""
    spec = load_go1_spec()
    set_solver(spec, config)
    # Visual-only content: meshes, textures, materials (no effect on physics; bodies have inertials).
    strip_visuals(spec)
    # Feet-only contacts, with Playground's contact parameters.
    feet_only_contacts(spec, [spec.geom(f) for f in FEET])
    floor = spec.geom("floor")
    floor.priority, floor.condim = 1, 3
    floor.friction = [0.6, floor.friction[1], floor.friction[2]]
    for f in FEET:
        g = spec.geom(f)
        g.priority, g.condim = 0, 1
        g.solimp = [0.015, 1.0, 0.023, g.solimp[3], g.solimp[4]]
        g.friction = [0.8, 0.02, 0.01]
    # No joint damping; PD through the position actuators.
    for j in spec.joints:
        if j.type != mujoco.mjtJoint.mjJNT_FREE:
            j.damping = np.zeros_like(np.asarray(j.damping))
    for a in spec.actuators:
        a.gainprm[0] = config.kp
        a.biasprm[1] = -config.kp
        a.biasprm[2] = -config.kd
    spec.site("imu").pos = list(IMU_POS)
    key = spec.key("home")
    key.qpos = list(HOME_QPOS)
    key.ctrl = list(HOME_QPOS[7:])
    # Sensors (Playground's names).
    S, Ob = mujoco.mjtSensor, mujoco.mjtObj

    def add(name, type_, objtype=Ob.mjOBJ_SITE, objname="imu", **kw):
        spec.add_sensor(name=name, type=type_, objtype=objtype, objname=objname, **kw)

    add("gyro", S.mjSENS_GYRO)
    add("local_linvel", S.mjSENS_VELOCIMETER)
    add("accelerometer", S.mjSENS_ACCELEROMETER)
    add("upvector", S.mjSENS_FRAMEZAXIS)
    add("global_linvel", S.mjSENS_FRAMELINVEL)
    add("global_angvel", S.mjSENS_FRAMEANGVEL)
    add("orientation", S.mjSENS_FRAMEQUAT)
    for f in FEET:
        add(f"{f}_global_linvel", S.mjSENS_FRAMELINVEL, objname=f)
        add(f"{f}_pos", S.mjSENS_FRAMEPOS, objname=f)
    for f in FEET:
        # data="found", reduce="mindist", num=1: 1 if the foot touches the floor.
        add(f"{f}_floor_found", S.mjSENS_CONTACT, objtype=Ob.mjOBJ_GEOM, objname=f,
            reftype=Ob.mjOBJ_GEOM, refname="floor", intprm=[1, 1, 1])
    for a in spec.actuators:
        add(f"{a.name}_force", S.mjSENS_ACTUATORFRC, objtype=Ob.mjOBJ_ACTUATOR, objname=a.name)
    return spec


# --------------------------------------------------------------------------------------------------
# The numpy task
# --------------------------------------------------------------------------------------------------
class Go1JoystickFlat(base.Task):
    def __init__(self, config: Go1JoystickConfig, num_envs: int, seed: int):
        super().__init__(config, num_envs, seed)
        c = config
        nsub = round(c.ctrl_dt / c.sim_dt)
        if nsub < 1 or abs(nsub * c.sim_dt - c.ctrl_dt) > 1e-9:
            raise ValueError(f"ctrl_dt {c.ctrl_dt} must be a multiple of sim_dt {c.sim_dt}")
        self.dt = c.ctrl_dt
        self.model = self.build_spec(c).compile()
        m = self.model
        M = self.num_envs
        self._rng = r = np.random.Generator(np.random.Philox(self.seed))
        home = m.key("home")
        self.init_qpos = np.array(home.qpos)
        self.default_pose = self.init_qpos[7:].copy()
        self.pose_weight = np.array(POSE_WEIGHT)
        lowers, uppers = m.jnt_range[1:].T
        self.soft_lower = lowers * c.soft_joint_pos_limit_factor
        self.soft_upper = uppers * c.soft_joint_pos_limit_factor
        self.floor_id = m.geom("floor").id
        self.torso_id = m.body("trunk").id
        self._sensor = sensor_index(m)
        self._noise_scale = noise_scales(c)
        self.scales = reward_scales(c)
        self._cmd_a = np.array(c.command_a)
        self._cmd_b = np.array(c.command_b)
        # Domain randomisation: per-env numpy parameters and per-env model copies.
        self.dr = self._sample_dr()
        delays = actuation.sample_delays(r, c.dr_action_delay, M) if c.domain_randomization else None
        if delays is not None:
            self.dr["action_delay"] = delays[:, None].astype(np.float64)
        self.delay = actuation.ActionDelay(np.zeros(M) if delays is None else delays, c.dr_action_delay[1], m.nu)
        self.extrinsics = self._extrinsics()
        models = self._apply_dr() if c.domain_randomization else None
        self.sim = BatchedSim(m, M, nsub, engine=c.physics_engine, models=models,
                              sensors_every_substep=c.sensors_every_substep)
        self.spec = base.TaskSpec(
            name="go1_joystick_flat", obs_dim=OBS_DIM, critic_obs_dim=CRITIC_OBS_DIM, action_dim=m.nu,
            episode_length=c.episode_length, ctrl_dt=c.ctrl_dt, reward_terms=REWARD_TERMS,
            privileged_dim=self.extrinsics.shape[1],
        )
        # Per-env episode state (Playground's ``info``).
        self.command = np.zeros((M, 3))
        self.steps_until_next_cmd = np.zeros(M, dtype=np.int64)
        self.last_act = np.zeros((M, m.nu))
        self.last_last_act = np.zeros((M, m.nu))
        self.feet_air_time = np.zeros((M, 4))
        self.last_contact = np.zeros((M, 4), dtype=bool)
        self.swing_peak = np.zeros((M, 4))
        self.steps = np.zeros(M, dtype=np.int64)
        self.unstable_count = 0

    def build_spec(self, config: Go1JoystickConfig) -> mujoco.MjSpec:
        """The task's model (a subclass may edit it: ``tasks/go1_rough.py`` swaps the floor for terrain)."""
        return build_spec(config)

    # ---- domain randomisation -----------------------------------------------------------------
    def _sample_dr(self) -> dict[str, np.ndarray]:
        c, M, r = self.config, self.num_envs, self._rng
        nb = self.model.nbody - 1  # world has no mass
        if not c.domain_randomization:
            return {
                "floor_friction": np.full((M, 1), 0.6), "frictionloss_scale": np.ones((M, 12)),
                "armature_scale": np.ones((M, 12)), "com_offset": np.zeros((M, 3)),
                "mass_scale": np.ones((M, nb)), "torso_mass_delta": np.zeros((M, 1)),
                "default_pose_offset": np.zeros((M, 12)), "motor_strength": np.ones((M, 12)),
            }
        lo, hi = c.dr_motor_strength
        return {
            "floor_friction": r.uniform(*c.dr_floor_friction, size=(M, 1)),
            "frictionloss_scale": r.uniform(*c.dr_frictionloss_scale, size=(M, 12)),
            "armature_scale": r.uniform(*c.dr_armature_scale, size=(M, 12)),
            "com_offset": r.uniform(-c.dr_com_offset, c.dr_com_offset, size=(M, 3)),
            "mass_scale": r.uniform(*c.dr_link_mass_scale, size=(M, nb)),
            "torso_mass_delta": r.uniform(-c.dr_torso_mass_delta, c.dr_torso_mass_delta, size=(M, 1)),
            "default_pose_offset": r.uniform(
                -c.dr_default_pose_offset, c.dr_default_pose_offset, size=(M, 12)
            ),
            # Drawn last and only when enabled, so the other draws (and parity runs) are unchanged.
            "motor_strength": r.uniform(lo, hi, size=(M, 12)) if hi > lo else np.full((M, 12), lo),
        }

    def _extrinsics(self) -> np.ndarray:
        """[M, privileged_dim] float32: the DR parameters, in ``self.extrinsics_layout`` order."""
        self.extrinsics_layout = tuple((k, self.dr[k].shape[1]) for k in sorted(self.dr))
        return np.concatenate([self.dr[k] for k in sorted(self.dr)], axis=1).astype(np.float32)

    def _apply_dr(self) -> list[mujoco.MjModel]:
        base_m, dr = self.model, self.dr
        models = []
        for i in range(self.num_envs):
            mi = copy.copy(base_m)
            mi.geom_friction[self.floor_id, 0] = dr["floor_friction"][i, 0]
            mi.dof_frictionloss[6:] = base_m.dof_frictionloss[6:] * dr["frictionloss_scale"][i]
            mi.dof_armature[6:] = base_m.dof_armature[6:] * dr["armature_scale"][i]
            mi.body_ipos[self.torso_id] = base_m.body_ipos[self.torso_id] + dr["com_offset"][i]
            mi.body_mass[1:] = base_m.body_mass[1:] * dr["mass_scale"][i]
            mi.body_mass[self.torso_id] += dr["torso_mass_delta"][i, 0]
            mi.qpos0[7:] = base_m.qpos0[7:] + dr["default_pose_offset"][i]
            mi.actuator_gainprm[:, 0] = base_m.actuator_gainprm[:, 0] * dr["motor_strength"][i]
            mi.actuator_biasprm[:, 1:3] = base_m.actuator_biasprm[:, 1:3] * dr["motor_strength"][i][:, None]
            models.append(mi)
        return models

    # ---- helpers --------------------------------------------------------------------------------
    def _s(self, name: str) -> np.ndarray:
        adr, dim = self._sensor[name]
        return self.sim.sensordata[:, adr : adr + dim]

    def _sensors(self) -> dict[str, np.ndarray]:
        return read_sensors(self.sim.sensordata, self._sensor, self.model.nu)

    def constants(self) -> dict[str, np.ndarray]:
        """The per-task constants of ``step_math`` (float64)."""
        return {"default_pose": self.default_pose, "pose_weight": self.pose_weight, "soft_lower": self.soft_lower,
                "soft_upper": self.soft_upper}

    def info(self) -> dict[str, np.ndarray]:
        """The per-env episode state ``step_math`` reads (Playground's ``info``)."""
        return {"command": self.command, "last_act": self.last_act, "feet_air_time": self.feet_air_time,
                "last_contact": self.last_contact, "swing_peak": self.swing_peak}

    def _noise(self) -> np.ndarray:
        M = self.num_envs
        return self._rng.uniform(-1.0, 1.0, size=(M, self._noise_scale.size)) * self._noise_scale

    def _pose_offset(self, idx=slice(None)) -> np.ndarray:
        if not self.config.dr_pose_offset_on_targets:
            return np.zeros_like(self.dr["default_pose_offset"][idx])
        return self.dr["default_pose_offset"][idx]

    def _targets(self, action: np.ndarray) -> np.ndarray:
        return self.default_pose + self._pose_offset() + action * self.config.action_scale

    def _observe(self, s: dict[str, np.ndarray], last_act, command, last_contact, air_time):
        noise = self._noise()
        return self.extend_obs(*observe(s, self.sim.qpos[:, 7:], self.sim.qvel[:, 6:], last_act, command,
                                        last_contact, air_time, self.default_pose, noise))

    def extend_obs(self, obs: np.ndarray, critic_obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(obs, critic_obs) of the current state with what a subclass appends (nothing here; the rough task's
        height scan)."""
        return obs, critic_obs

    def base_states(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(qpos [n, nq], qvel [n, nv]) of new episodes of envs ``idx`` (a subclass moves them: the rough task's
        cells)."""
        c = self.config
        return random_base_states(self.init_qpos, self.model.nv, idx.size, self._rng, c.reset_xy, c.reset_yaw,
                                  c.reset_base_vel)

    def at_limit(self) -> np.ndarray:
        """[M] bool: episodes truncated after this step (the time limit; the rough task adds leaving the map)."""
        return self.steps >= self.config.episode_length

    def _exp_steps(self, n: int) -> np.ndarray:
        t = self._rng.exponential(1.0, size=n) * self.config.command_resample_mean_s
        return np.round(t / self.dt).astype(np.int64)

    def _reset_envs(self, idx: np.ndarray) -> None:
        r, n = self._rng, idx.size
        qpos, qvel = self.base_states(idx)
        ctrl = self.default_pose + self._pose_offset(idx)
        self.sim.set_state(idx, qpos, qvel, ctrl=ctrl)
        self.delay.reset(idx)
        self.steps_until_next_cmd[idx] = self._exp_steps(n)
        self.command[idx] = r.uniform(-self._cmd_a, self._cmd_a, size=(n, 3))
        self.last_act[idx] = 0.0
        self.last_last_act[idx] = 0.0
        self.feet_air_time[idx] = 0.0
        self.last_contact[idx] = False
        self.swing_peak[idx] = 0.0
        self.steps[idx] = 0

    # ---- API ------------------------------------------------------------------------------------
    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        self._reset_envs(np.arange(self.num_envs))
        obs, cobs = self._observe(self._sensors(), self.last_act, self.command, self.last_contact,
                                  self.feet_air_time)
        return obs.astype(np.float32), cobs.astype(np.float32)

    def step(self, action: np.ndarray) -> base.StepOut:
        M = self.num_envs
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(M, self.model.nu), -1.0, 1.0)
        a = np.nan_to_num(a, nan=0.0)
        unstable = self.sim.step(self._targets(self.delay.apply(a)))
        return self._after_physics(a, unstable)

    def _after_physics(self, a: np.ndarray, unstable: np.ndarray) -> base.StepOut:
        """The rest of ``step`` once ``self.sim`` holds the post-physics state and sensors (the parity
        tests call it on a state set with ``sim.set_state``)."""
        c, M = self.config, self.num_envs
        noise = self._noise()
        next_obs, next_cobs, done, scaled, reward, updated = step_math(
            self._sensors(), self.sim.qpos[:, 7:], self.sim.qvel[:, 6:], a, self.info(), noise, self.constants(),
            c, self.scales, self.dt,
        )
        next_obs, next_cobs = self.extend_obs(next_obs, next_cobs)
        self.last_last_act = self.last_act
        self.steps_until_next_cmd -= 1
        due = self.steps_until_next_cmd <= 0
        if due.any():
            r = self._rng
            new = sample_command(
                self.command, r.uniform(-self._cmd_a, self._cmd_a, size=(M, 3)),
                r.random((M, 3)) < self._cmd_b, r.random((M, 3)) < 0.5,
            )
            self.command = np.where(due[:, None], new, self.command)
            self.steps_until_next_cmd = np.where(due, self._exp_steps(M), self.steps_until_next_cmd)
        self.last_act = updated["last_act"]
        self.feet_air_time = updated["feet_air_time"]
        self.last_contact = updated["last_contact"]
        self.swing_peak = updated["swing_peak"]
        self.steps += 1
        out, n_unstable = base.finish_step(next_obs, next_cobs, reward, scaled, done, unstable, self.at_limit(),
                                           self._reset_and_observe)
        self.unstable_count += n_unstable
        return out

    def _reset_and_observe(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._reset_envs(idx)
        return self._observe(self._sensors(), self.last_act, self.command, self.last_contact, self.feet_air_time)

    def base_velocity(self) -> np.ndarray:
        """[M, 3] measured (vx, vy) in the body frame and yaw rate: what ``command`` asks for (walking metric)."""
        return np.concatenate([self._s("local_linvel")[:, :2], self._s("gyro")[:, 2:3]], axis=1)

    def close(self) -> None:
        self.sim.close()


def make(config: Go1JoystickConfig, num_envs: int, seed: int) -> Go1JoystickFlat:
    return Go1JoystickFlat(config, num_envs, seed)
