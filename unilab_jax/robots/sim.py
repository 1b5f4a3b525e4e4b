"""MuJoCo-backed robots that behave like physical ones.

``SimRobot(SimConfig(arm="franka", task="pick_place"))`` implements the ``Robot`` contract:

* real-time pacing: a step takes ``1 / (control_hz * speed)`` wall seconds (``speed=inf``: unpaced);
* a step called more than one period after the previous one returned is *late*: the robot has been
  holding its last command meanwhile, so the missed periods are simulated with that command (at most
  ``max_hold_periods``) and counted in ``health().late_actions``;
* actuator latency and jitter: a command reaches the servos ``latency_s + |N(0, jitter_s)|`` simulated
  seconds after the step starts (a command later than the period applies during the next one);
* Gaussian noise on proprioception; RGB cameras (``front``, ``wrist``) rendered with ``mujoco.Renderer``
  (``camera_geometry="collision"`` draws the arm with its collision geometry instead of its visual meshes: the
  Franka's ~400k mesh vertices cost 15 ms a frame at any size in software GL, its collision shapes ~1.5 ms);
* resets that block for ``reset_seconds / speed`` wall seconds;
* end-effector control: the action moves a target tcp pose; damped-least-squares IK turns it into
  joint-position targets for the arm's servos, so every arm shares one action space;
* safety limits (``config.limits``, ``robots.limits``): the target pose clamped into the workspace box and
  orientation cone, the joint targets' step and forward kinematics checked, protective stops on the measured
  pose, tcp speed and contact force; ``health().limit_hits`` counts each.

Proprioception ``[13]``: tcp position (3), tcp orientation as the first two columns of its rotation
matrix (6), tcp linear velocity (3), gripper opening in [0, 1] (1 = open).
Privileged ``[8 + task.state_dim]``: exact tcp position (3), tcp quaternion (4), gripper opening (1),
then the task state (see ``robots.manipulation``).
"""

from __future__ import annotations

import dataclasses
import time

import mujoco
import numpy as np

from unilab_jax.robots import ik, limits, scenes
from unilab_jax.robots.interface import (
    PROTECTIVE_STOP,
    Health,
    Robot,
    RobotError,
    RobotEstopped,
    RobotFaulted,
    RobotSpec,
    Step,
    check_action,
)
from unilab_jax.robots.manipulation import TASKS, make_task

PROPRIO_DIM = 13
CAMERAS = ("front", "wrist")
CAMERA_GEOMETRY = ("visual", "collision")
HIDDEN_GROUP = 5  # geom group the cameras leave out (the visual meshes with camera_geometry="collision")
# The tcp may wander this far from its measured position (no wind-up while pushing against contact).
MAX_TARGET_LEAD = 0.05
TARGET_LOW, TARGET_HIGH = limits.SafetyLimits().target_box()


@dataclasses.dataclass(frozen=True)
class SimConfig:
    arm: str = "franka"  # a key of scenes.ARMS
    task: str = "pick_place"  # a key of tasks.TASKS
    name: str = ""  # defaults to f"{arm}_{task}"
    control_hz: float = 10.0
    timestep: float = 0.002
    speed: float = 1.0  # wall-clock speed-up; inf: unpaced
    latency_s: float = 0.0  # actuator latency (simulated seconds)
    jitter_s: float = 0.0  # std of the extra |normal| latency
    proprio_noise: float = 0.001  # std of the noise on every proprioceptive entry
    cameras: tuple[str, ...] = CAMERAS
    image_size: int = 64
    camera_geometry: str = "visual"  # what the cameras draw of the arm: its visual meshes, or its collision geometry
    reset_seconds: float = 2.0  # how long a reset blocks at speed 1
    dense_reward: bool = False
    max_delta_pos: float = 0.03  # metres per step at |action| = 1
    max_delta_rot: float = 0.25  # radians per step at |action| = 1
    tcp_start_noise: float = 0.02  # uniform +- offset of the starting tcp position (x, y)
    max_hold_periods: int = 10
    limits: limits.SafetyLimits = limits.SafetyLimits()
    seed: int = 0

    def __post_init__(self):
        if self.arm not in scenes.ARMS:
            raise ValueError(f"unknown arm {self.arm!r}; choose one of {sorted(scenes.ARMS)}")
        if self.task not in TASKS:
            raise ValueError(f"unknown task {self.task!r}; choose one of {sorted(TASKS)}")
        unknown = set(self.cameras) - set(CAMERAS)
        if unknown:
            raise ValueError(f"unknown cameras {sorted(unknown)}; available: {CAMERAS}")
        if not 16 <= self.image_size <= 256:
            raise ValueError(f"image_size must be in [16, 256], got {self.image_size}")
        if not self.speed > 0 or not self.control_hz > 0 or not self.timestep > 0:
            raise ValueError(f"speed, control_hz and timestep must be positive, got {self.speed}, {self.control_hz}, "
                             f"{self.timestep}")
        finite = (self.latency_s, self.jitter_s, self.proprio_noise, self.reset_seconds)
        if not all(np.isfinite(v) and v >= 0 for v in finite):
            raise ValueError(f"latency_s, jitter_s, proprio_noise and reset_seconds must be finite and >= 0, got "
                             f"{finite}")
        if self.camera_geometry not in CAMERA_GEOMETRY:
            raise ValueError(f"camera_geometry must be one of {CAMERA_GEOMETRY}, got {self.camera_geometry!r}")
        substeps = 1.0 / (self.control_hz * self.timestep)
        if abs(substeps - round(substeps)) > 1e-6:
            raise ValueError(f"1 / (control_hz * timestep) = {substeps} must be an integer")


def gripper_ctrl(command: float, info: scenes.ArmInfo) -> float:
    """Gripper command in [-1 (open), 1 (closed)] -> the gripper actuator's control value."""
    return info.gripper_open + (command + 1.0) / 2.0 * (info.gripper_closed - info.gripper_open)


def gripper_opening(qpos: np.ndarray, info: scenes.ArmInfo) -> float:
    """Opening in [0 (closed), 1 (open)] from the gripper joints' positions [k]."""
    lo, hi = np.array(info.gripper_joint_closed), np.array(info.gripper_joint_open)
    return float(np.clip(np.mean((qpos - lo) / (hi - lo)), 0.0, 1.0))


def proprio_vector(tcp_pos: np.ndarray, tcp_mat: np.ndarray, tcp_vel: np.ndarray, opening: float) -> np.ndarray:
    """[13] = tcp position (3), rotation matrix columns 0 and 1 (6), linear velocity (3), opening (1)."""
    mat = np.asarray(tcp_mat).reshape(3, 3)
    return np.concatenate([tcp_pos, mat[:, 0], mat[:, 1], tcp_vel, [opening]])


def apply_delta(pos: np.ndarray, quat: np.ndarray, action: np.ndarray, max_dpos: float, max_drot: float,
                low: np.ndarray = TARGET_LOW, high: np.ndarray = TARGET_HIGH) -> tuple[np.ndarray, np.ndarray]:
    """New target (pos [3] clipped to [low, high], quat [4]) after a clipped action [7]: world-frame translation
    and rotation."""
    new_pos = np.clip(pos + action[:3] * max_dpos, low, high)
    new_quat = ik.quat_mul(ik.quat_from_rotvec(action[3:6] * max_drot), quat)
    return new_pos, new_quat / np.linalg.norm(new_quat)


class SimRobot(Robot):
    """A simulated arm + task behind the Robot contract (see the module docstring)."""

    def __init__(self, config: SimConfig = SimConfig()):
        self.config = config
        self.info = scenes.ARMS[config.arm]
        self.task = make_task(config.task, config.arm, config.dense_reward)
        spec = scenes.build_arm(config.arm)
        self.task.build(spec)
        spec.option.timestep = config.timestep
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self._scratch = mujoco.MjData(self.model)
        self.ix = scenes.index(self.model, self.info)
        self.task.bind(self.model)
        self.substeps = round(1.0 / (config.control_hz * config.timestep))
        size = config.image_size
        self.spec = RobotSpec(
            name=config.name or f"{config.arm}_{config.task}", kind=config.arm, task=config.task,
            proprio_dim=PROPRIO_DIM, privileged_dim=8 + self.task.state_dim, cameras=tuple(config.cameras),
            image_shape=(size, size, 3), control_hz=config.control_hz, episode_length=self.task.episode_length,
            max_delta_pos=config.max_delta_pos, max_delta_rot=config.max_delta_rot, speed=config.speed,
            reset_seconds=config.reset_seconds)
        self._rng = np.random.default_rng(config.seed)
        self._renderer = None
        self._scene_option = mujoco.MjvOption()
        if config.camera_geometry == "collision":
            m = self.model
            visual = (m.geom_type == mujoco.mjtGeom.mjGEOM_MESH) & (m.geom_contype == 0) & (m.geom_conaffinity == 0)
            m.geom_group[:] = np.where(visual, HIDDEN_GROUP, 0)
            self._scene_option.geomgroup[HIDDEN_GROUP] = 0
        self._home_q = self._solve_home()
        self._state = "ok"
        self._detail = ""
        self._ready = False
        self._counts = {"steps": 0, "late_actions": 0, "resets": 0, "overruns": 0}
        self._limit_hits = dict.fromkeys(limits.LIMIT_HITS, 0)
        # the arm's and gripper's bodies (their contact forces are limited): the tree under the hand's root
        self._arm_bodies = self.model.body_rootid == self.model.body_rootid[self.ix.hand_body]
        self._pending: list[tuple[int, np.ndarray]] = []  # (substeps until applied, ctrl [nu])
        self._last_return: float | None = None
        self._t = 0
        self._target_pos = np.zeros(3)
        self._target_quat = np.array(scenes.HOME_TCP_QUAT)
        self._potential = 0.0  # the task's potential after the last step (reset: of the initial state)

    # ---------------------------------------------------------------------------------------------
    # Contract
    # ---------------------------------------------------------------------------------------------
    def connect(self) -> None:
        """Creates the camera renderer (needs a working MUJOCO_GL backend when cameras are configured)."""
        if self.config.cameras and self._renderer is None:
            size = self.config.image_size
            try:
                self._renderer = mujoco.Renderer(self.model, size, size)
            except Exception as e:  # noqa: BLE001  (GL setup errors come in many types)
                raise RobotError(
                    f"cannot create an offscreen renderer ({type(e).__name__}: {e}); set MUJOCO_GL=egl "
                    "(needs libegl1, libegl-mesa0, libgl1-mesa-dri, libopengl0) or MUJOCO_GL=osmesa (libosmesa6) "
                    "before mujoco is imported, or configure the robot without cameras") from e
            # Shadows and reflections cost ~10x the frame time in software GL (llvmpipe).
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False

    def reset(self, seed: int | None = None) -> dict[str, np.ndarray]:
        start = time.perf_counter()
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self.connect()
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        offset = np.zeros(3)
        offset[:2] = self._rng.uniform(-self.config.tcp_start_noise, self.config.tcp_start_noise, 2)
        home_pos = np.array(scenes.HOME_TCP) + offset
        home_quat = np.array(scenes.HOME_TCP_QUAT)
        q = self._ik(self._home_q, home_pos, home_quat, iterations=30)
        d.qpos[self.ix.qpos] = q
        grip = 1.0 if self.task.grip_closed_at_reset else -1.0
        d.ctrl[self.ix.ctrl] = q
        d.ctrl[self.ix.gripper_ctrl] = gripper_ctrl(grip, self.info)
        if grip > 0:
            d.qpos[self.ix.gripper_qpos] = self.info.gripper_joint_closed
        self.task.randomize(m, d, self._rng)
        mujoco.mj_forward(m, d)
        self._target_pos = d.site_xpos[self.ix.tcp_site].copy()
        self._target_quat = ik.mat_to_quat(d.site_xmat[self.ix.tcp_site])
        self._potential = self.task.potential(self.task.state(m, d), d.site_xpos[self.ix.tcp_site])
        self._pending.clear()
        self._t = 0
        self._state, self._detail, self._ready = "ok", "", True
        self._counts["resets"] += 1
        obs = self._observe()
        self._sleep_until(start + self.spec.reset_wall_s)
        self._last_return = time.perf_counter()
        return obs

    def step(self, action: np.ndarray) -> Step:
        start = time.perf_counter()
        a = check_action(action)
        if self._state == "estopped":
            raise RobotEstopped(f"emergency stop engaged{f' ({self._detail})' if self._detail else ''}: call "
                                "clear_estop() or reset()")
        if self._state == "faulted":
            raise RobotFaulted(f"robot faulted ({self._detail}): call reset()")
        if not self._ready:
            raise RobotError("call reset() before step()")
        late = self._hold_missed_periods(start)
        ctrl = self.data.ctrl.copy()
        ctrl[self.ix.ctrl] = self._arm_command(a)
        ctrl[self.ix.gripper_ctrl] = gripper_ctrl(a[6], self.info)
        self._pending.append((self._delay_substeps(), ctrl))
        self._simulate_period()
        self._t += 1
        self._counts["steps"] += 1
        if not np.all(np.isfinite(self.data.qpos)):
            self._state, self._detail, self._ready = "faulted", "simulation diverged", False
            raise RobotFaulted("simulation diverged: call reset()")
        self._check_measured()
        obs = self._observe()
        state = self.task.state(self.model, self.data)
        tcp = self.data.site_xpos[self.ix.tcp_site]
        reward, success = self.task.reward(state, tcp, self._potential)
        self._potential = self.task.potential(state, tcp)
        truncated = self._t >= self.spec.episode_length and not success
        if success or truncated:
            self._ready = False
        if self.spec.period_s and time.perf_counter() > start + self.spec.period_s:
            self._counts["overruns"] += 1
        self._sleep_until(start + self.spec.period_s)
        self._last_return = time.perf_counter()
        return Step(obs, float(reward), bool(success), bool(truncated),
                    {"success": bool(success), "late": late, "t": self._t})

    def estop(self) -> None:
        """Holds the arm at its current joint positions; drops commands still in flight."""
        self._pending.clear()
        self.data.ctrl[self.ix.ctrl] = self.data.qpos[self.ix.qpos]
        self._target_pos = self.data.site_xpos[self.ix.tcp_site].copy()
        self._target_quat = ik.mat_to_quat(self.data.site_xmat[self.ix.tcp_site])
        if self._state != "faulted":
            self._state = "estopped"

    def clear_estop(self) -> None:
        if self._state == "estopped":
            self._state, self._detail = "ok", ""
            self._last_return = time.perf_counter()

    def health(self) -> Health:
        return Health(self._state, detail=self._detail, limit_hits=dict(self._limit_hits), **self._counts)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # ---------------------------------------------------------------------------------------------
    # Safety limits (robots.limits)
    # ---------------------------------------------------------------------------------------------
    def _arm_command(self, a: np.ndarray) -> np.ndarray:
        """The arm's joint targets for action ``a``, inside every command limit (each clamp counted)."""
        lim, c = self.config.limits, self.config
        low, high = lim.target_box()
        pos, quat = apply_delta(self._target_pos, self._target_quat, a, c.max_delta_pos, c.max_delta_rot,
                                low=np.full(3, -np.inf), high=np.full(3, np.inf))
        inside = np.clip(pos, low, high)
        self._hit("workspace", not np.array_equal(inside, pos))
        self._target_quat, clamped = limits.clamp_to_cone(quat, np.radians(lim.cone_deg))
        self._hit("orientation", clamped)
        tcp = self.data.site_xpos[self.ix.tcp_site]
        self._target_pos = np.clip(tcp + np.clip(inside - tcp, -MAX_TARGET_LEAD, MAX_TARGET_LEAD), low, high)
        q_now = self.data.qpos[self.ix.qpos].copy()
        q_cmd, limited = limits.limit_joint_step(q_now, self._ik(q_now, self._target_pos, self._target_quat),
                                                 lim.max_joint_speed / c.control_hz)
        self._hit("joint_velocity", limited)
        # The joint target itself must put the tcp inside the box and the cone (an unreachable target pose
        # makes IK trade position for orientation): else scale it back towards the measured joints. A tcp that
        # is outside already (pushed) may move back, not farther out.
        allowed, scale, delta = self._command_violation(q_now), 1.0, q_cmd - q_now
        while scale > 1e-3 and self._command_violation(q_now + scale * delta) > allowed:
            scale /= 2
        self._hit("kinematics", scale < 1.0)
        return q_now + (scale if scale > 1e-3 else 0.0) * delta

    def _command_violation(self, q: np.ndarray) -> float:
        """How far joints ``q`` put the tcp outside the box less half the margin and the cone (+ the kinematic
        slack): ``SafetyLimits.violation`` of their forward kinematics."""
        self._scratch.qpos[:] = self.data.qpos
        self._scratch.qpos[self.ix.qpos] = q
        mujoco.mj_kinematics(self.model, self._scratch)
        return self._violation(self._scratch, -self.config.limits.margin / 2, limits.KINEMATIC_CONE_SLACK_DEG)

    def _violation(self, d: mujoco.MjData, slack: float, cone_slack_deg: float) -> float:
        site = self.ix.tcp_site
        return self.config.limits.violation(d.site_xpos[site], ik.mat_to_quat(d.site_xmat[site]), slack,
                                            cone_slack_deg)

    def _check_measured(self) -> None:
        """A protective stop (an estop whose detail names the limit) when the measured tcp pose, tcp speed or
        a contact force is beyond its limit."""
        lim = self.config.limits
        vel = np.zeros(6)
        mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_SITE, self.ix.tcp_site, vel, 0)
        speed = float(np.linalg.norm(vel[3:]))
        force = limits.contact_force(self.model, self.data, self._arm_bodies)
        for name, beyond, what in (
                ("pose", self._violation(self.data, lim.pose_slack, lim.cone_slack_deg) > 0,
                 "tcp pose outside the workspace"),
                ("tcp_speed", speed > lim.max_tcp_speed, f"tcp speed {speed:.2f} m/s > {lim.max_tcp_speed}"),
                ("force", force > lim.max_force, f"contact force {force:.0f} N > {lim.max_force:g}")):
            if beyond:
                self._hit(name, True)
                self.estop()
                self._detail = f"{PROTECTIVE_STOP}: {what}"

    def _hit(self, name: str, hit: bool) -> None:
        self._limit_hits[name] += int(hit)

    # ---------------------------------------------------------------------------------------------
    # Simulation
    # ---------------------------------------------------------------------------------------------
    def _ik(self, q0: np.ndarray, pos: np.ndarray, quat: np.ndarray, iterations: int = 3) -> np.ndarray:
        self._scratch.qpos[:] = self.data.qpos
        self._scratch.qpos[self.ix.qpos] = q0
        return ik.solve_ik(self.model, self._scratch, self.ix.tcp_site, self.ix.qpos, self.ix.dof,
                           self.ix.ctrl_range, pos, quat, iterations=iterations)

    def _solve_home(self) -> np.ndarray:
        mujoco.mj_resetData(self.model, self.data)
        return self._ik(np.array(self.info.home_qpos), np.array(scenes.HOME_TCP), np.array(scenes.HOME_TCP_QUAT),
                        iterations=100)

    def _delay_substeps(self) -> int:
        c = self.config
        delay = c.latency_s + (abs(self._rng.normal(0.0, c.jitter_s)) if c.jitter_s > 0 else 0.0)
        return int(round(delay / c.timestep))

    def _simulate_period(self) -> None:
        m, d = self.model, self.data
        for _ in range(self.substeps):
            if self._pending:
                self._pending = [(n - 1, ctrl) for n, ctrl in self._pending]
                while self._pending and self._pending[0][0] < 0:
                    d.ctrl[:] = self._pending.pop(0)[1]
            mujoco.mj_step(m, d)

    def _hold_missed_periods(self, now: float) -> bool:
        """Simulates the periods the robot spent holding its last command; True when this action is late."""
        period = self.spec.period_s
        if period == 0.0 or self._last_return is None:
            return False
        missed = int((now - self._last_return) / period)
        if missed < 1:
            return False
        self._counts["late_actions"] += 1
        for _ in range(min(missed, self.config.max_hold_periods)):
            self._simulate_period()
        return True

    def _observe(self) -> dict[str, np.ndarray]:
        m, d = self.model, self.data
        site = self.ix.tcp_site
        vel = np.zeros(6)
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_SITE, site, vel, 0)
        opening = gripper_opening(d.qpos[self.ix.gripper_qpos], self.info)
        proprio = proprio_vector(d.site_xpos[site], d.site_xmat[site], vel[3:], opening)
        if self.config.proprio_noise > 0:
            proprio = proprio + self._rng.normal(0.0, self.config.proprio_noise, proprio.shape)
        quat = ik.mat_to_quat(d.site_xmat[site])
        privileged = np.concatenate([d.site_xpos[site], quat, [opening], self.task.state(m, d)])
        obs = {"proprio": proprio.astype(np.float32), "privileged": privileged.astype(np.float32)}
        for cam in self.config.cameras:
            self._renderer.update_scene(d, camera=cam, scene_option=self._scene_option)
            obs[cam] = self._renderer.render().copy()
        return obs

    @staticmethod
    def _sleep_until(deadline: float) -> None:
        while True:
            left = deadline - time.perf_counter()
            if left <= 0:
                return
            time.sleep(left)
