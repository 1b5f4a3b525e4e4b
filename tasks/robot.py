"""``robot_pick_place`` / ``robot_peg_insertion``: a task whose environments are robots (docs/ROBOTS.md).

With ``robots`` (an inventory of ``tcp://HOST:PORT`` robot servers, ``unilab_jax.robots.inventory``) each
of the task's ``num_envs`` environments is one robot claimed from the inventory: the first free ones in
order, so workers of one run given the same inventory share it out among themselves (a claim is
exclusive; ``connect_timeout_s`` bounds the wait for free robots). Without ``robots`` the environments
are in-process simulated robots (``arm``, unpaced, rendering ``cameras`` if any): for tests and the task contract.

Observation (state-based): the robot's ``proprio`` [13], (with ``policy_state``) its ``privileged`` state,
a one-hot of its kind (``KINDS``) and a one-hot of its place in the inventory (the robot's identity; one
slot without an inventory; none with ``robot_identity`` off). Critic observation:
the observation, the robot's privileged state (without ``critic_state``: not) and the episode time
``t / episode_length``. ``observation(i)`` is env ``i``'s last robot observation as the robot sent it
(privileged state included: what the scripted expert reads).

Image observation (``cameras``, e.g. ``("front",)``; ``image_size``; ``frame_stack``): beside the observation
above (the proprioception), the policy sees the cameras' last ``frame_stack`` frames as one uint8 image
``spec.image_shape = (S, S, 3 x cameras x frame_stack)``, channels ``[frame][camera][rgb]``, the oldest frame
first. Each env keeps its own stack; an episode starts with its first frame repeated. ``images()`` returns the
stacks of the current observations (what the policy acts on), and every transition carries ``image`` /
``next_image`` (the stack of ``obs`` and of ``next_obs``, before auto-reset) as task fields. In-process robots
render the cameras (``MUJOCO_GL`` must name a working backend, e.g. ``egl``, before mujoco is imported); a
robot server sends what it renders (``python -m unilab_jax.robots.serve --cameras=front --image_size=64``) and
must render every camera of ``cameras`` at ``image_size`` (``camera_mismatch``), else it cannot join.
Reward: the robot's (one term, ``task``). An episode ends when the robot says so (success: terminated;
its time limit: truncated) or after ``episode_length`` steps (truncated).

``lock_rotation`` zeroes the rotation part of every action (the policy's and the operator's): the tcp keeps
its starting orientation (peg insertion: a learner's small rotation commands integrate into a tilt or
yaw that jams the square peg).

Operator channel (``operator``, ``unilab_jax.robots.operator``): ``gate`` lets the scripted expert, acting
as a human operator, take over an env's robot when the policy leaves the safe region, drops the object or
stalls, for ``operator_segment`` steps; ``always`` has it drive whole episodes (demonstrations). The
executed action is the transition's ``action``, and every transition records who chose it in the
``source`` field (0 policy, 1 operator; ``SOURCE_POLICY`` / ``SOURCE_OPERATOR``). Per episode the task
reports ``intervention_rate`` (operator steps / steps) and ``interventions`` (takeovers) as episode
metrics (logged as ``episode/intervention_rate``, ``episode/interventions``), and ``late_fraction``: the share of
the episode's steps whose action reached the robot after a full control period (the robot held its last command
meanwhile; ``info["late"]`` of each step), the measure of whether the learner and the policy keep up with
robots in real time. The operator runs here,
beside the robot client, so it works the same for robots behind remote servers.

Robots step concurrently (one thread each; a step blocks for a control period). A lost robot (its server
does not answer, or a step or reset fails) interrupts the step (``tasks.base.StepInterrupted``: no
transition, every env reset): the task first waits, calling ``keepalive`` and retrying every ``retry_s``,
until the robot's server or another free robot of the inventory answers and resets (the robot
*rejoins*). ``losses`` / ``rejoins`` count this. A protective stop (the robot refused the policy's command on a
safety limit) interrupts the step the same way, unless ``stop_ends_episode`` is set (the evaluations set it,
``training.evaluation.run_episodes``): then it ends that robot's episode only, truncated without success and marked
in ``extras["protective_stop"]``, and the other robots' episodes go on.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import time

import numpy as np

from tasks import base
from unilab_jax.fields import IMAGE_FIELDS
from unilab_jax.robots.client import RobotClient
from unilab_jax.robots.interface import (
    Robot,
    RobotClaimed,
    RobotDisconnected,
    RobotError,
    RobotSpec,
    Step,
    is_protective_stop,
)
from unilab_jax.robots.inventory import check_address, client_keys, compatible
from unilab_jax.robots.operator import ExpertOperator, OperatorConfig

KINDS = ("franka", "ur5e")
REWARD_TERMS = ("task",)
SOURCE_POLICY, SOURCE_OPERATOR = 0, 1
EPISODE_METRICS = ("intervention_rate", "interventions", "late_fraction")
CAMERAS = ("front", "wrist")  # what the simulated robots render (unilab_jax.robots.sim.CAMERAS)
CAMERA_GEOMETRY = ("visual", "collision")  # unilab_jax.robots.sim.CAMERA_GEOMETRY


@dataclasses.dataclass(frozen=True)
class RobotTaskConfig:
    """Configuration of the robot tasks (override any field by name)."""

    robots: tuple[str, ...] = ()  # robot server addresses (the inventory); (): in-process simulated robots
    # Keyed servers (robots.keys): per robot its public key (Z85; "" for a server without keys), and the path of
    # this client's NAME.key_secret (robots.inventory.Inventory.task_overrides fills them from the TOML); unused
    # without robots (a saved run played on in-process robots)
    server_keys: tuple[str, ...] = ()
    client_key: str = ""
    arm: str = "franka"  # in-process robots only
    episode_length: int = 100  # control steps before truncation (at most the robot's own limit)
    dense_reward: bool = True  # in-process robots only (servers choose theirs: --dense_reward)
    # The policy also sees the robot's privileged state (object poses): a state-based stand-in for cameras,
    # simulated robots only (a physical robot sends no privileged state).
    policy_state: bool = False
    # The critic observation holds the privileged state too (an asymmetric actor-critic). Off: the critic reads
    # what the policy reads (with cameras: proprioception and images, as DrQ and SERL's critics do).
    critic_state: bool = True
    cameras: tuple[str, ...] = ()  # image observation from these cameras (see the module docstring); (): none
    image_size: int = 64  # pixels per side of each camera's frame (robot servers must render this size)
    frame_stack: int = 1  # frames per camera in the image observation (the last ones, oldest first)
    # In-process robots and the sim: servers a robot experiment starts: what their cameras draw of the arm (visual
    # meshes, or the ~10x cheaper collision shapes).
    camera_geometry: str = "visual"
    timeout_s: float = 2.0  # a robot that does not answer a call within this (+ its period) is lost
    lease_s: float = 5.0
    connect_timeout_s: float = 60.0  # wait for free robots when the task is built
    # 0: all num_envs robots must be claimed. k > 0: after connect_timeout_s go on with the robots claimed
    # if there are at least k (num_envs shrinks to their count): evaluations on the robots that are left.
    min_envs: int = 0
    retry_s: float = 1.0  # between attempts to reach a lost robot
    operator: str = "off"  # the operator channel: off, gate (takes over when needed) or always (demonstrations)
    operator_segment: int = 20  # control steps per takeover (gate)
    operator_stall_steps: int = 15  # policy steps without reward progress before a takeover (gate)
    operator_box: tuple[float, ...] = OperatorConfig.box  # safe tcp region (x, y, z) low then high (gate)
    # Zero the rotation command (action[3:6], after any operator's): the tcp keeps the orientation it starts with,
    # as a safety pose box without rotation room would. The executed action is the transition's.
    lock_rotation: bool = False
    # The observation holds the one-hot of the robot's inventory slot (its identity). Off: a policy that is
    # evaluated on robots it never trained on (the robot experiments' periodic evaluation claims the robots the
    # workers leave free) sees no slot it never saw: an unseen slot's column has variance 0 in the observation
    # statistics, so it reaches the policy normalised to the clip bound, 10.
    robot_identity: bool = True

    def image_shape(self) -> tuple[int, ...]:
        """``(S, S, 3 x cameras x frame_stack)`` of the image observation; () without cameras."""
        return (self.image_size, self.image_size, 3 * len(self.cameras) * self.frame_stack) if self.cameras else ()

    def operator_config(self) -> OperatorConfig:
        return OperatorConfig(mode=self.operator, segment_steps=self.operator_segment,
                              stall_steps=self.operator_stall_steps, box=tuple(self.operator_box))

    def __post_init__(self):
        for address in self.robots:
            check_address(address)
        if self.robots and self.server_keys and len(self.server_keys) != len(self.robots):
            raise ValueError(f"server_keys needs one key per robot ({len(self.robots)}), got {len(self.server_keys)}")
        if self.robots and any(self.server_keys) and not self.client_key:
            raise ValueError("keyed robot servers (server_keys) need client_key, this client's NAME.key_secret")
        if self.episode_length < 1:
            raise ValueError(f"episode_length must be positive, got {self.episode_length}")
        if self.min_envs < 0:
            raise ValueError(f"min_envs must be >= 0, got {self.min_envs}")
        if self.arm not in KINDS:
            raise ValueError(f"arm must be one of {KINDS}, got {self.arm!r}")
        if set(self.cameras) - set(CAMERAS) or len(set(self.cameras)) != len(self.cameras):
            raise ValueError(f"cameras must be distinct names of {CAMERAS}, got {self.cameras}")
        if not 16 <= self.image_size <= 256:
            raise ValueError(f"image_size must be in [16, 256], got {self.image_size}")
        if self.camera_geometry not in CAMERA_GEOMETRY:
            raise ValueError(f"camera_geometry must be one of {CAMERA_GEOMETRY}, got {self.camera_geometry!r}")
        if self.frame_stack < 1:
            raise ValueError(f"frame_stack must be >= 1, got {self.frame_stack}")
        self.operator_config()  # checks the operator fields


def default_config() -> RobotTaskConfig:
    return RobotTaskConfig()


def camera_mismatch(config: RobotTaskConfig, spec: RobotSpec) -> str:
    """"" when a robot of ``spec`` sends the images ``config`` asks for, else what is missing."""
    if not config.cameras:
        return ""
    missing = [c for c in config.cameras if c not in spec.cameras]
    size = (config.image_size, config.image_size, 3)
    if missing or tuple(spec.image_shape) != size:
        return (f"the task wants cameras {list(config.cameras)} at {size}, the robot renders {list(spec.cameras)} at "
                f"{tuple(spec.image_shape)} (serve it with --cameras={','.join(config.cameras)} "
                f"--image_size={config.image_size})")
    return ""


class RobotTask(base.Task):
    def __init__(self, config: RobotTaskConfig, num_envs: int, seed: int, task: str):
        super().__init__(config, num_envs, seed)
        self.task_name = task
        self.losses = 0
        self.rejoins = 0
        self.stop_ends_episode = False  # a protective stop ends that robot's episode instead of interrupting the step
        self.robots: list[Robot] = []
        self.slots: list[int] = []  # each env's place in the inventory (its identity)
        try:
            if config.robots:
                self._keys = client_keys(config.server_keys or ("",) * len(config.robots), config.client_key)
                if num_envs > len(config.robots):
                    raise ValueError(f"{num_envs} environments need {num_envs} robots; the inventory has "
                                     f"{len(config.robots)}: {list(config.robots)}")
                self._claim_initial()
            else:
                self._make_local()
        except BaseException:
            self.close()
            raise
        spec = self.robots[0].spec
        self.robot_spec = spec
        self.n_ids = max(len(config.robots), 1) if config.robot_identity else 0
        self.length = min(config.episode_length, spec.episode_length)
        obs_dim = spec.proprio_dim + len(KINDS) + self.n_ids + (spec.privileged_dim if config.policy_state else 0)
        image_shape = config.image_shape()
        images = tuple((name, image_shape, "uint8") for name in IMAGE_FIELDS) if config.cameras else ()
        critic_obs_dim = obs_dim + (spec.privileged_dim if config.critic_state else 0) + 1
        self.spec = base.TaskSpec(name=f"robot_{task}", obs_dim=obs_dim, critic_obs_dim=critic_obs_dim,
                                  action_dim=spec.action_dim,
                                  episode_length=self.length, ctrl_dt=1.0 / spec.control_hz, reward_terms=REWARD_TERMS,
                                  transition_fields=(("source", (), "uint8"), *images),
                                  episode_metrics=EPISODE_METRICS, success_on_termination=True, image_shape=image_shape)
        n = self.num_envs  # fewer than asked when min_envs let the task go on with the robots it claimed
        self._stack = np.zeros((n, *image_shape), np.uint8)  # each env's frame stack (cameras only)
        self.set_operator(config.operator)
        self.steps = np.zeros(n, np.int64)
        self._late = np.zeros(n, np.int64)  # per env: this episode's steps whose action came late (``info["late"]``)
        self._last = [dict[str, np.ndarray]() for _ in range(n)]
        # In-process cameras render in the thread that created their GL context: no step threads then.
        threads = n > 1 and not (config.cameras and not config.robots)
        self._threads = concurrent.futures.ThreadPoolExecutor(n) if threads else None

    # ---- robots ---------------------------------------------------------------------------------------
    def _make_local(self) -> None:
        from unilab_jax.robots.sim import SimConfig, SimRobot

        for i in range(self.num_envs):
            robot = SimRobot(SimConfig(arm=self.config.arm, task=self.task_name, cameras=self.config.cameras,
                                       image_size=self.config.image_size, camera_geometry=self.config.camera_geometry,
                                       speed=float("inf"), reset_seconds=0.0,
                                       dense_reward=self.config.dense_reward, seed=self.seed * 1000 + i))
            robot.connect()
            self.robots.append(robot)
            self.slots.append(0)

    def _try_claim(self, slot: int) -> RobotClient | None:
        """A connected client of the inventory's robot ``slot``, or None if it is claimed or silent."""
        c = self.config
        client = RobotClient(c.robots[slot], timeout_s=c.timeout_s, lease_s=c.lease_s, keys=self._keys[slot])
        try:
            client.connect()
        except (RobotClaimed, RobotDisconnected):
            client.close()
            return None
        except BaseException:
            client.close()
            raise
        problem = ((compatible(self.robots[0].spec, client.spec) if self.robots else "")
                   or camera_mismatch(c, client.spec))
        if client.spec.task != self.task_name or problem:
            client.close()
            raise ValueError(f"robot {c.robots[slot]} ({client.spec.name}, task {client.spec.task}) cannot join "
                             f"task robot_{self.task_name}" + (f": {problem}" if problem else ""))
        return client

    def _claim_initial(self) -> None:
        deadline = time.monotonic() + self.config.connect_timeout_s
        while len(self.robots) < self.num_envs:
            for slot in range(len(self.config.robots)):
                if slot not in self.slots and len(self.robots) < self.num_envs:
                    client = self._try_claim(slot)
                    if client is not None:
                        self.robots.append(client)
                        self.slots.append(slot)
            if len(self.robots) < self.num_envs:
                if time.monotonic() > deadline:
                    if self.config.min_envs and len(self.robots) >= self.config.min_envs:
                        self.num_envs = len(self.robots)
                        return
                    raise RuntimeError(f"{self.num_envs} robots wanted, {len(self.robots)} free within "
                                       f"{self.config.connect_timeout_s:.0f} s in {list(self.config.robots)}")
                self._sleep(self.config.retry_s)

    def _sleep(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self.keepalive()
            time.sleep(min(left, 0.2))

    def _rejoin(self, i: int) -> dict[str, np.ndarray]:
        """Env ``i`` lost its robot: waits until its own server, or another free robot, answers; resets it."""
        self.losses += 1
        if isinstance(self.robots[i], RobotClient):
            self.robots[i].close()
        while True:
            self.keepalive()
            if not self.config.robots:  # an in-process robot: a reset clears its fault
                obs = self.robots[i].reset()
                self.rejoins += 1
                return obs
            mine = self.slots[i]
            for slot in [mine] + [s for s in range(len(self.config.robots)) if s not in self.slots]:
                client = self._try_claim(slot)
                if client is None:
                    continue
                try:
                    obs = client.reset()
                except RobotError:
                    client.close()
                    continue
                self.robots[i], self.slots[i] = client, slot
                self.rejoins += 1
                return obs
            self._sleep(self.config.retry_s)

    # ---- observations ---------------------------------------------------------------------------------
    def _obs(self, i: int, robot_obs: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        kind = np.zeros(len(KINDS), np.float32)
        kind[KINDS.index(self.robots[i].spec.kind)] = 1.0
        ident = np.zeros(self.n_ids, np.float32)
        if self.n_ids:
            ident[self.slots[i]] = 1.0
        state = [robot_obs["privileged"].astype(np.float32)] if self.config.policy_state else []
        obs = np.concatenate([robot_obs["proprio"].astype(np.float32), *state, kind, ident])
        t = np.array([self.steps[i] / self.length], np.float32)
        critic = [robot_obs["privileged"].astype(np.float32)] if self.config.critic_state else []
        return obs, np.concatenate([obs, *critic, t])

    def observation(self, i: int) -> dict[str, np.ndarray]:
        """Env ``i``'s last robot observation (``proprio``, ``privileged``, camera frames), as the robot sent it."""
        return self._last[i]

    def _observe_all(self) -> tuple[np.ndarray, np.ndarray]:
        pairs = [self._obs(i, self._last[i]) for i in range(self.num_envs)]
        return np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs])

    def _frames(self, envs) -> np.ndarray:
        """uint8 [len(envs), S, S, 3 x cameras]: the current frame of each env in ``envs`` (cameras in order)."""
        return np.stack([np.concatenate([self._last[i][c] for c in self.config.cameras], axis=-1) for i in envs])

    def _restack(self, envs) -> None:
        """Starts the frame stacks of ``envs`` (new episodes): the current frame repeated. Into a new array: the
        stacks handed out (``images()``, a step's ``image`` / ``next_image``) never change afterwards."""
        envs = list(envs)
        if self.config.cameras and envs:
            stack = self._stack.copy()
            stack[envs] = np.tile(self._frames(envs), (1, 1, 1, self.config.frame_stack))
            self._stack = stack

    def images(self) -> np.ndarray:
        if not self.config.cameras:
            return super().images()
        return self._stack

    def _map(self, fn, *args) -> list:
        """``fn(i, *args_i)`` for every env, concurrently; an exception is returned in its place."""

        def call(i, *a):
            try:
                return fn(i, *a)
            except RobotError as e:
                return e

        if self._threads is None:
            return [call(i, *(a[i] for a in args)) for i in range(self.num_envs)]
        return list(self._threads.map(call, range(self.num_envs), *args))

    def _reset_all(self, lost: set[int]) -> None:
        """Brings the ``lost`` envs' robots back, resets the others (a robot lost meanwhile is brought back)."""
        got = self._map(lambda i: None if i in lost else self.robots[i].reset())
        for i, g in enumerate(got):
            self._last[i] = self._rejoin(i) if i in lost or isinstance(g, RobotError) else g
        self.steps[:] = 0
        self._late[:] = 0
        for op in self.operators:
            op.reset()
        self._restack(range(self.num_envs))

    def set_operator(self, mode: str) -> None:
        """Switches the operator channel (``off``, ``gate``, ``always``; HG-DAgger's phases); call ``reset`` next."""
        op_config = dataclasses.replace(self.config, operator=mode).operator_config()
        self.operators = [ExpertOperator(r.spec, op_config) for r in self.robots] if mode != "off" else []

    # ---- the Task contract ----------------------------------------------------------------------------
    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        self._reset_all(set())
        return self._observe_all()

    def step(self, action: np.ndarray) -> base.StepOut:
        a = np.nan_to_num(np.asarray(action, np.float32).reshape(self.num_envs, -1), nan=0.0)
        a = np.clip(a, -1.0, 1.0)
        source = np.full(self.num_envs, SOURCE_POLICY, np.uint8)
        for i, op in enumerate(self.operators):
            a[i], by_operator = op.act(self._last[i], a[i])
            source[i] = SOURCE_OPERATOR if by_operator else SOURCE_POLICY
        if self.config.lock_rotation:
            a[:, 3:6] = 0.0
        got = self._map(lambda i, ai: self.robots[i].step(ai), list(a))
        lost = {i for i, g in enumerate(got) if isinstance(g, RobotError)}
        stopped = np.zeros(self.num_envs, bool)
        if lost and self.stop_ends_episode and all(is_protective_stop(got[i]) for i in lost):
            for i in lost:  # the episode ends where the robot stopped: no success, and reset below like any end
                got[i] = Step(self._last[i], 0.0, False, True, {"success": False, "late": False})
                stopped[i] = True
            lost = set()
        if lost:  # no transition for anyone: every env starts again once the lost robots are back
            reason = "; ".join(f"{self.config.robots[self.slots[i]] if self.config.robots else i}: "
                               f"{type(got[i]).__name__}: {got[i]}" for i in sorted(lost))
            self._reset_all(lost)
            raise base.StepInterrupted(reason, *self._observe_all())
        self.steps += 1
        self._late += np.array([bool(g.info["late"]) for g in got])
        reward = np.array([g.reward for g in got], np.float32)
        term = np.array([g.terminated for g in got], bool)
        trunc = (np.array([g.truncated for g in got], bool) | (self.steps >= self.length)) & ~term
        for i, g in enumerate(got):
            self._last[i] = g.obs
        extras = {"source": source, "intervention_rate": np.zeros(self.num_envs, np.float32),
                  "interventions": np.zeros(self.num_envs, np.float32),
                  "late_fraction": (self._late / self.steps).astype(np.float32)}
        if self.stop_ends_episode:
            extras["protective_stop"] = stopped
        if self.operators or self.config.lock_rotation:
            extras["action"] = a
        for i, op in enumerate(self.operators):
            op.observe(float(reward[i]))
            extras["intervention_rate"][i], extras["interventions"][i] = op.rate, op.takeovers
        next_obs, next_critic = self._observe_all()
        done = np.flatnonzero(term | trunc)
        obs, critic = next_obs, next_critic
        if self.config.cameras:  # shift each stack by one frame (into a new array, as _restack)
            per_frame = 3 * len(self.config.cameras)
            extras["image"] = self._stack
            extras["next_image"] = np.concatenate([self._stack[..., per_frame:], self._frames(range(self.num_envs))],
                                                  axis=-1)
            self._stack = extras["next_image"]
        if done.size:
            fresh = self._map(lambda i, d: self.robots[i].reset() if d else None, list(term | trunc))
            for i in done:  # the step happened: a robot lost while resetting starts its next episode on return
                self._last[i] = self._rejoin(i) if isinstance(fresh[i], RobotError) else fresh[i]
                if self.operators:
                    self.operators[i].reset()
            self.steps[done] = 0
            self._late[done] = 0
            self._restack(done)
            obs, critic = self._observe_all()
        return base.StepOut(obs, critic, next_obs, next_critic, reward, term, trunc, {"task": reward.copy()}, extras)

    def close(self) -> None:
        if getattr(self, "_threads", None) is not None:
            self._threads.shutdown()
        for robot in self.robots:
            robot.close()
        self.robots = []


def make(task: str, config: RobotTaskConfig, num_envs: int, seed: int) -> RobotTask:
    return RobotTask(config, num_envs, seed, task)
