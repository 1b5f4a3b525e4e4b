"""Manipulation tasks of the RLinf-USER kind: peg insertion and pick-and-place into a bin; and a reach task
whose target only the cameras show (the image learners' test).

A task adds its objects to an arm's MjSpec (``build``), finds them in the compiled model (``bind``),
places them at random at each reset (``randomize``) and reads the privileged state the reward and the
scripted experts need (``state``). Success and the progress potential are pure numpy functions of that
state (``success``, ``potential``), so they can be tested with hand-made numbers. The robot owns the
MjModel / MjData and remembers the previous step's potential.

Reward (``reward``): 1 on success only (a success detector's), or with ``dense_reward`` the potential-based
shaping (Ng, Harada & Russell 1999) ``SUCCESS_BONUS * success + potential(s') - potential(s)``. The episode
ends on success, so a reward that paid the potential itself (up to 1 per step) made hovering near the goal
worth up to ``1 / (1 - gamma)`` (20 at gamma 0.95) against a success bonus of 1: learners never finished.
With the difference, the shaping terms of any trajectory sum to ``potential(last) - potential(first)``
(at most 1), so finishing dominates (``shaped_reward``).

State vectors (float64, world frame, metres):

* ``peg_insertion``: ``[tip (3), hole (3), tip - hole (3)]``: the peg's tip; the centre of the hole's
  opening; their difference (what the task asks to close to within 1.5 mm, given directly to policies).
* ``pick_place``: ``[object (3), object quat (4), bin (3)]``: the cube's centre and orientation;
  the centre of the bin's floor.
* ``reach``: ``[target (3), tcp - target (3)]``: a flat green disc on the table (visual only, nothing
  collides with it) placed at random; success: the tcp within ``reach_radius`` of it in the plane, at any height.
  The proprioception holds the tcp, never the target: a policy finds it in the images (front or wrist camera).
"""

from __future__ import annotations

import abc
import dataclasses

import mujoco
import numpy as np

from unilab_jax.robots.ik import yaw_of_quat
from unilab_jax.robots.scenes import ARMS

# Collision bits: 1 = everything by default; 2 = the held peg, which touches only the block and floor.
_PEG_BIT = 2


@dataclasses.dataclass(frozen=True)
class PegGeometry:
    peg_half: float = 0.01  # square peg, half width
    peg_length: float = 0.08
    peg_offset: float = 0.02  # peg centre beyond the tcp along the approach axis
    clearance: float = 0.0015  # per side
    block_half: float = 0.04
    block_height: float = 0.05
    depth: float = 0.02  # insertion depth counted as success

    @property
    def hole_half(self) -> float:
        return self.peg_half + self.clearance

    @property
    def tip_offset(self) -> float:
        """Distance from the tcp to the peg tip along the approach axis."""
        return self.peg_offset + self.peg_length / 2


@dataclasses.dataclass(frozen=True)
class BinGeometry:
    cube_half: float = 0.02
    cube_mass: float = 0.05
    bin_half: float = 0.07  # inner half width
    wall_height: float = 0.05
    wall_half_thickness: float = 0.005


# The dense reward's payment for success: ten times the whole shaping budget (potentials lie in [0, 1]).
SUCCESS_BONUS = 10.0


def shaped_reward(potential: float, previous: float, success: bool, bonus: float = SUCCESS_BONUS) -> float:
    """``bonus * success + potential - previous``: the dense reward of a step from the potential before
    (``previous``) and after it (``potential``)."""
    return float(bonus * float(success) + potential - previous)


class ManipulationTask(abc.ABC):
    """One task on one arm. Subclasses set ``name``, ``episode_length``, ``state_dim``, ``arms``."""

    name: str
    episode_length: int
    state_dim: int
    arms: tuple[str, ...]
    grip_closed_at_reset: bool = False

    def __init__(self, kind: str, dense_reward: bool):
        if kind not in self.arms:
            raise ValueError(f"task {self.name!r} supports arms {self.arms}, not {kind!r}")
        self.kind = kind
        self.dense_reward = bool(dense_reward)

    @abc.abstractmethod
    def build(self, spec: mujoco.MjSpec) -> None:
        """Adds the task's bodies to the arm scene."""

    @abc.abstractmethod
    def bind(self, model: mujoco.MjModel) -> None:
        """Looks up the task's ids in the compiled model."""

    @abc.abstractmethod
    def randomize(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None:
        """Places the objects for a new episode (before ``mj_forward``)."""

    @abc.abstractmethod
    def state(self, model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
        """Privileged task state [state_dim] (see the module docstring)."""

    @abc.abstractmethod
    def success(self, state: np.ndarray, tcp: np.ndarray) -> bool:
        """Whether the task state and the tcp position [3] count as success (the episode then ends)."""

    @abc.abstractmethod
    def potential(self, state: np.ndarray, tcp: np.ndarray) -> float:
        """Progress towards success in [0, 1] (the dense reward's potential)."""

    def reward(self, state: np.ndarray, tcp: np.ndarray, previous: float) -> tuple[float, bool]:
        """(reward, success) of a step that ended in ``state`` / ``tcp``; ``previous``: the potential
        before the step (read by the dense reward only)."""
        success = self.success(state, tcp)
        if not self.dense_reward:
            return float(success), success
        return shaped_reward(self.potential(state, tcp), previous, success), success


# --------------------------------------------------------------------------------------------------
# Peg insertion
# --------------------------------------------------------------------------------------------------
def peg_success(tip: np.ndarray, hole: np.ndarray, g: PegGeometry) -> bool:
    """The tip is inside the hole's footprint and at least ``g.depth`` below its opening."""
    inside = bool(np.all(np.abs(tip[:2] - hole[:2]) < g.hole_half))
    return inside and bool(tip[2] < hole[2] - g.depth)


def peg_potential(tip: np.ndarray, hole: np.ndarray, g: PegGeometry) -> float:
    """In [0, 1]: the mean of reaching (closeness of the tip to the bottom of the required insertion, 10 / m)
    and alignment (closeness of the tip to the hole's axis, 100 / m). Reaching alone hardly tells a peg
    jammed on the block's top 5 mm off the axis from one over the opening (0.005 apart); alignment does."""
    goal = hole - np.array([0.0, 0.0, g.depth])
    reach = 1.0 - np.tanh(10.0 * np.linalg.norm(tip - goal))
    align = 1.0 - np.tanh(100.0 * np.linalg.norm(tip[:2] - hole[:2]))
    return float(0.5 * (reach + align))


class PegInsertion(ManipulationTask):
    """A square peg held rigidly in the closed gripper goes into a hole (1.5 mm clearance per side)
    of a block placed at random on the table."""

    name = "peg_insertion"
    episode_length = 100
    state_dim = 9
    arms = ("franka", "ur5e")
    grip_closed_at_reset = True
    block_x = (0.42, 0.58)
    block_y = (-0.12, 0.12)

    def __init__(self, kind: str, dense_reward: bool = False, geometry: PegGeometry = PegGeometry()):
        super().__init__(kind, dense_reward)
        self.g = geometry

    def build(self, spec: mujoco.MjSpec) -> None:
        g = self.g
        arm = ARMS[self.kind]
        tcp = np.array(arm.tcp_local)
        peg = spec.body(arm.hand_body).add_body(name="peg", pos=list(tcp + [0, 0, g.peg_offset]))
        peg.add_geom(name="peg", type=mujoco.mjtGeom.mjGEOM_BOX, size=[g.peg_half, g.peg_half, g.peg_length / 2],
                     mass=0.05, contype=_PEG_BIT, conaffinity=_PEG_BIT, rgba=[0.85, 0.45, 0.1, 1.0])
        peg.add_site(name="peg_tip", pos=[0, 0, g.peg_length / 2], size=[0.003] * 3, group=5)
        spec.geom("floor").conaffinity = 1 | _PEG_BIT
        block = spec.worldbody.add_body(name="block", mocap=True, pos=[0.5, 0.0, 0.0])
        h, b, height = g.hole_half, g.block_half, g.block_height
        wall = (b - h) / 2
        for i, (x, y, sx, sy) in enumerate([(h + wall, 0.0, wall, b), (-h - wall, 0.0, wall, b),
                                            (0.0, h + wall, h, wall), (0.0, -h - wall, h, wall)]):
            block.add_geom(name=f"block{i}", type=mujoco.mjtGeom.mjGEOM_BOX, pos=[x, y, height / 2],
                           size=[sx, sy, height / 2], contype=1 | _PEG_BIT, conaffinity=1 | _PEG_BIT,
                           rgba=[0.2, 0.45, 0.75, 1.0])

    def bind(self, model: mujoco.MjModel) -> None:
        self._tip = model.site("peg_tip").id
        self._mocap = model.body("block").mocapid[0]

    def randomize(self, model, data, rng):
        data.mocap_pos[self._mocap] = [rng.uniform(*self.block_x), rng.uniform(*self.block_y), 0.0]
        data.mocap_quat[self._mocap] = [1.0, 0.0, 0.0, 0.0]

    def state(self, model, data):
        hole = data.mocap_pos[self._mocap] + [0.0, 0.0, self.g.block_height]
        tip = data.site_xpos[self._tip]
        return np.concatenate([tip, hole, tip - hole])

    def success(self, state, tcp):
        return peg_success(state[:3], state[3:6], self.g)

    def potential(self, state, tcp):
        return peg_potential(state[:3], state[3:6], self.g)


# --------------------------------------------------------------------------------------------------
# Pick and place
# --------------------------------------------------------------------------------------------------
def in_bin(obj: np.ndarray, bin_pos: np.ndarray, g: BinGeometry) -> bool:
    """The object's centre lies inside the bin's walls and below their top."""
    inside = bool(np.all(np.abs(obj[:2] - bin_pos[:2]) < g.bin_half))
    return inside and bool(obj[2] < bin_pos[2] + g.wall_height)


def pick_place_potential(obj: np.ndarray, tcp: np.ndarray, bin_pos: np.ndarray, g: BinGeometry) -> float:
    """In [0, 1]: mean of reaching the object, lifting it, and bringing it over the bin once lifted."""
    reach = 1.0 - np.tanh(10.0 * np.linalg.norm(tcp - obj))
    lifted = float(obj[2] > 2.5 * g.cube_half)
    over_bin = 1.0 - np.tanh(5.0 * np.linalg.norm(obj[:2] - bin_pos[:2]))
    return float((reach + lifted + lifted * over_bin) / 3.0)


class PickPlace(ManipulationTask):
    """A small cube at a random position and yaw goes into a bin (placed at random near a fixed spot)."""

    name = "pick_place"
    episode_length = 100
    state_dim = 10
    arms = ("franka", "ur5e")
    object_x = (0.4, 0.58)
    object_y = (-0.02, 0.16)
    bin_x = (0.44, 0.52)
    bin_y = (-0.26, -0.2)

    def __init__(self, kind: str, dense_reward: bool = False, geometry: BinGeometry = BinGeometry()):
        super().__init__(kind, dense_reward)
        self.g = geometry

    def build(self, spec: mujoco.MjSpec) -> None:
        g = self.g
        cube = spec.worldbody.add_body(name="object", pos=[0.5, 0.05, g.cube_half])
        cube.add_freejoint(name="object")
        cube.add_geom(name="object", type=mujoco.mjtGeom.mjGEOM_BOX, size=[g.cube_half] * 3, mass=g.cube_mass,
                      friction=[1.0, 0.01, 0.001], rgba=[0.85, 0.15, 0.15, 1.0])
        bin_body = spec.worldbody.add_body(name="bin", mocap=True, pos=[0.48, -0.23, 0.0])
        t, h, hw = g.wall_half_thickness, g.bin_half, g.wall_height / 2
        bin_body.add_geom(name="bin_floor", type=mujoco.mjtGeom.mjGEOM_BOX, pos=[0, 0, t],
                          size=[h + 2 * t, h + 2 * t, t], rgba=[0.3, 0.6, 0.3, 1.0])
        for i, (x, y, sx, sy) in enumerate([(h + t, 0, t, h + 2 * t), (-h - t, 0, t, h + 2 * t),
                                            (0, h + t, h, t), (0, -h - t, h, t)]):
            bin_body.add_geom(name=f"bin_wall{i}", type=mujoco.mjtGeom.mjGEOM_BOX, pos=[x, y, hw], size=[sx, sy, hw],
                              rgba=[0.3, 0.6, 0.3, 1.0])

    def bind(self, model: mujoco.MjModel) -> None:
        joint = model.joint("object")
        self._qpos = joint.qposadr[0]
        self._dof = joint.dofadr[0]
        self._body = model.body("object").id
        self._mocap = model.body("bin").mocapid[0]

    def randomize(self, model, data, rng):
        yaw = rng.uniform(-np.pi / 4, np.pi / 4)
        data.qpos[self._qpos:self._qpos + 3] = [rng.uniform(*self.object_x), rng.uniform(*self.object_y),
                                                self.g.cube_half]
        data.qpos[self._qpos + 3:self._qpos + 7] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
        data.qvel[self._dof:self._dof + 6] = 0.0
        data.mocap_pos[self._mocap] = [rng.uniform(*self.bin_x), rng.uniform(*self.bin_y), 0.0]

    def state(self, model, data):
        return np.concatenate([data.xpos[self._body], data.xquat[self._body], data.mocap_pos[self._mocap]])

    def success(self, state, tcp):
        return in_bin(state[:3], state[7:10], self.g)

    def potential(self, state, tcp):
        return pick_place_potential(state[:3], tcp, state[7:10], self.g)


def object_yaw(state: np.ndarray) -> float:
    """Yaw of the pick-and-place cube from its state vector (radians)."""
    return yaw_of_quat(state[3:7])


# --------------------------------------------------------------------------------------------------
# Reach a target seen only by the cameras
# --------------------------------------------------------------------------------------------------
def reach_potential(tcp: np.ndarray, target: np.ndarray) -> float:
    """In [0, 1]: closeness of the tcp to the target in the plane (10 / m)."""
    return float(1.0 - np.tanh(10.0 * np.linalg.norm(tcp[:2] - target[:2])))


class Reach(ManipulationTask):
    """The tcp goes over a green disc placed at random on the table (gripper open, nothing to grasp)."""

    name = "reach"
    episode_length = 100
    state_dim = 6
    arms = ("franka", "ur5e")
    target_x = (0.35, 0.55)
    target_y = (-0.12, 0.12)
    target_radius = 0.03
    reach_radius = 0.02  # success: the tcp this close to the target's centre in the plane

    def build(self, spec: mujoco.MjSpec) -> None:
        target = spec.worldbody.add_body(name="target", mocap=True, pos=[0.45, 0.0, 0.0])
        target.add_geom(name="target", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[self.target_radius, 0.001, 0],
                        pos=[0, 0, 0.001], contype=0, conaffinity=0, rgba=[0.1, 0.8, 0.2, 1.0])

    def bind(self, model: mujoco.MjModel) -> None:
        self._mocap = model.body("target").mocapid[0]
        self._tcp = model.site("tcp").id

    def randomize(self, model, data, rng):
        data.mocap_pos[self._mocap] = [rng.uniform(*self.target_x), rng.uniform(*self.target_y), 0.0]

    def state(self, model, data):
        target = data.mocap_pos[self._mocap]
        return np.concatenate([target, data.site_xpos[self._tcp] - target])

    def success(self, state, tcp):
        return bool(np.linalg.norm(tcp[:2] - state[:2]) < self.reach_radius)

    def potential(self, state, tcp):
        return reach_potential(tcp, state[:3])


TASKS: dict[str, type[ManipulationTask]] = {PegInsertion.name: PegInsertion, PickPlace.name: PickPlace,
                                            Reach.name: Reach}


def make_task(name: str, kind: str, dense_reward: bool = False) -> ManipulationTask:
    """Task ``name`` (a key of TASKS) for arm ``kind``."""
    if name not in TASKS:
        raise ValueError(f"unknown robot task {name!r}; choose one of {sorted(TASKS)}")
    return TASKS[name](kind, dense_reward)
