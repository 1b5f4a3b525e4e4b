"""The robot contract: what a physical-robot driver, a simulated robot and a network client implement.

A robot is one arm in one scene, driven in end-effector space at a fixed wall-clock control rate::

    robot.connect()
    obs = robot.reset()                     # may block while the scene is restored
    step = robot.step(action)               # action [7] float32 in [-1, 1]; paced by the control rate
    step.obs, step.reward, step.terminated, step.truncated, step.info["success"]
    robot.estop(); robot.clear_estop()      # hold still, refuse steps / accept them again
    robot.health()                          # Health(state, steps, late_actions, resets, dropped_messages, ...)
    robot.close()

Observations are dicts of numpy arrays: ``"proprio"`` float32 ``[spec.proprio_dim]``, one uint8
``[H, W, 3]`` image per camera name in ``spec.cameras`` (absent when the robot has no cameras) and
``"privileged"`` float32 ``[spec.privileged_dim]`` (simulation only: object poses for scripted
experts and asymmetric critics; a physical robot sends an empty vector).

Action layout (shared by every arm, scaled inside the robot): ``[0:3]`` end-effector position delta
(x ``spec.max_delta_pos`` metres, world frame), ``[3:6]`` rotation delta as an axis-angle vector
(x ``spec.max_delta_rot`` radians, world frame), ``[6]`` gripper command (-1 open, +1 closed).

This module imports only the standard library and numpy.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, NamedTuple

import numpy as np

ACTION_LAYOUT = ("dx", "dy", "dz", "rx", "ry", "rz", "gripper")  # see the module docstring
ACTION_DIM = len(ACTION_LAYOUT)
HEALTH_STATES = ("ok", "estopped", "faulted", "disconnected")


class RobotError(RuntimeError):
    """Base class of errors a robot raises (and a server sends back by name)."""


class RobotDisconnected(RobotError):
    """The robot (or its server) did not answer in time or the connection is gone."""


class RobotEstopped(RobotError):
    """A step was refused because the emergency stop is engaged (``clear_estop`` or ``reset``)."""


PROTECTIVE_STOP = "protective stop"  # how an estop's detail (and so its RobotEstopped) begins when a limit made it


def is_protective_stop(error: BaseException) -> bool:
    """Whether ``error`` refused a step because the robot stopped itself on a safety limit (``robots.limits``):
    the commands that led there were the policy's, unlike a lost robot or an operator's stop button."""
    return isinstance(error, RobotEstopped) and f"({PROTECTIVE_STOP}:" in str(error)


class RobotClaimed(RobotError):
    """The robot is claimed by another client whose lease has not expired."""


class RobotFaulted(RobotError):
    """The robot is in a fault state (e.g. the simulation diverged); ``reset`` clears it."""


class BadRequest(RobotError):
    """A malformed, oversized or unknown request (the server keeps serving)."""


@dataclasses.dataclass(frozen=True)
class RobotSpec:
    """What a robot declares; a learner sizes its networks and buffers from it.

    ``image_shape`` is ``(H, W, 3)`` uint8 for every camera; ``cameras`` may be empty.
    ``control_hz`` is the nominal rate; at ``speed`` X one control period takes ``1 / (control_hz * X)``
    wall seconds (``speed == inf``: unpaced, for in-process tests).
    """

    name: str
    kind: str  # arm model, e.g. "franka" or "ur5e"
    task: str
    proprio_dim: int
    privileged_dim: int
    cameras: tuple[str, ...]
    image_shape: tuple[int, int, int]
    control_hz: float
    episode_length: int
    max_delta_pos: float
    max_delta_rot: float
    speed: float = 1.0
    reset_seconds: float = 0.0  # nominal (speed 1) duration of a reset
    action_dim: int = ACTION_DIM

    def __post_init__(self):
        if self.action_dim != ACTION_DIM:
            raise ValueError(f"action_dim must be {ACTION_DIM} (dpos 3 + drot 3 + gripper 1), got {self.action_dim}")
        if not self.control_hz > 0 or not self.speed > 0:
            raise ValueError(f"control_hz and speed must be positive, got {self.control_hz}, {self.speed}")
        if len(self.image_shape) != 3 or self.image_shape[2] != 3:
            raise ValueError(f"image_shape must be (H, W, 3), got {self.image_shape}")

    @property
    def period_s(self) -> float:
        """Wall seconds of one control period at this robot's speed (0 when unpaced)."""
        return 0.0 if self.speed == float("inf") else 1.0 / (self.control_hz * self.speed)

    @property
    def reset_wall_s(self) -> float:
        """Wall seconds a reset blocks at this robot's speed."""
        return 0.0 if self.speed == float("inf") else self.reset_seconds / self.speed

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RobotSpec:
        d = dict(d)
        d["cameras"] = tuple(d["cameras"])
        d["image_shape"] = tuple(d["image_shape"])
        return cls(**d)


@dataclasses.dataclass(frozen=True)
class Health:
    """Heartbeat state: ``state`` in HEALTH_STATES plus lifetime counters."""

    state: str
    steps: int = 0
    late_actions: int = 0  # steps whose action arrived after a full control period (last command held)
    resets: int = 0
    dropped_messages: int = 0  # replies not delivered (server) / requests that timed out (client)
    detail: str = ""
    owner: str = ""  # id of the client holding the robot (served robots; "" when free)
    overruns: int = 0  # steps whose own work (simulation, rendering) took longer than the control period
    # safety-limit counters (robots.limits.LIMIT_HITS: commands clamped, protective stops); served robots add
    # the server's (rate_limited: requests dropped by the per-client rate limit)
    limit_hits: dict[str, int] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if self.state not in HEALTH_STATES:
            raise ValueError(f"health state {self.state!r} not in {HEALTH_STATES}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class Step(NamedTuple):
    """One control step's result. ``info`` holds at least ``success`` (bool) and ``late`` (bool)."""

    obs: dict[str, np.ndarray]
    reward: float
    terminated: bool
    truncated: bool
    info: dict[str, Any]


def check_action(action: Any) -> np.ndarray:
    """``action`` -> float64 ``[7]`` clipped to [-1, 1]; raises ValueError on a wrong shape or non-finite values."""
    a = np.asarray(action, dtype=np.float64)
    if a.shape != (ACTION_DIM,):
        raise ValueError(f"action must have shape ({ACTION_DIM},), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"action must be finite, got {a.tolist()}")
    return np.clip(a, -1.0, 1.0)


class Robot(abc.ABC):
    """The contract every robot implements (simulated, physical, or a client of a robot server)."""

    spec: RobotSpec

    def connect(self) -> None:  # noqa: B027  (optional hook)
        """Acquires the hardware / connection (nothing by default)."""

    @abc.abstractmethod
    def reset(self, seed: int | None = None) -> dict[str, np.ndarray]:
        """Restores the scene (blocking for ``spec.reset_wall_s``); clears an estop; returns the first observation."""

    @abc.abstractmethod
    def step(self, action: np.ndarray) -> Step:
        """Applies one action [7] for one control period; never returns sooner than ``spec.period_s``.

        After a step that ends the episode (``terminated``: success; ``truncated``: time limit) the robot
        refuses steps until ``reset``."""

    @abc.abstractmethod
    def estop(self) -> None:
        """Emergency stop: the arm holds its current pose; ``step`` raises RobotEstopped until cleared."""

    @abc.abstractmethod
    def clear_estop(self) -> None:
        """Releases the emergency stop (the arm stays where it is)."""

    @abc.abstractmethod
    def health(self) -> Health:
        """Current state and counters."""

    def close(self) -> None:  # noqa: B027  (optional hook)
        """Releases the hardware / connection (nothing by default)."""

    def __enter__(self) -> Robot:
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
