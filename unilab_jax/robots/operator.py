"""The operator channel: someone (a teleop device, or here the scripted expert acting as one) who watches
the policy drive a robot and overrides its action.

``op = ExpertOperator(spec, OperatorConfig(mode="gate"))``; per episode ``op.reset()``; per control step
``action, by_operator = op.act(obs, policy_action)`` (``obs``: the robot's observation dict, the one the
policy acted on), then ``op.observe(reward)`` with the step's reward. Modes:

* ``gate`` (HG-DAgger's gating, Kelly et al. 2019): the operator takes control when the policy leaves the
  safe region (tcp outside ``box``), drops the object it was carrying (pick-and-place), or makes no
  progress (the episode's return so far has not risen above its best by ``stall_eps`` for ``stall_steps``
  steps; with the dense reward's potential-based shaping the return is the progress made); it then
  drives for ``segment_steps`` steps and hands control back. ``stall_steps`` start again at each hand-back.
  The scripted expert's phase machine runs on across an episode, on the policy's steps too (``watch``:
  it sees the policy reach a phase's switch), and at a takeover it resyncs to the state (``resync``: a
  cube held between closed fingers is carried on, not dropped by an earlier phase's open gripper).
* ``always``: the operator drives every step (whole-episode demonstrations).

Counters per episode: ``steps``, ``operator_steps``, ``takeovers``; ``rate`` = operator_steps / steps.
A teleop device would implement the same ``reset`` / ``act`` / ``observe`` (its ``act`` reading the
device and a clutch button instead of the triggers).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from unilab_jax.robots.experts import PickPlaceExpert, make_expert
from unilab_jax.robots.interface import RobotSpec
from unilab_jax.robots.manipulation import BinGeometry

MODES = ("off", "gate", "always")


@dataclasses.dataclass(frozen=True)
class OperatorConfig:
    """When the operator takes over and for how long (``mode`` one of ``MODES``)."""

    mode: str = "gate"
    segment_steps: int = 20  # control steps the operator drives per takeover
    stall_steps: int = 15  # policy steps without progress before a takeover
    watch: bool = True  # the expert's phase machine runs on the policy's steps too (a watching operator)
    stall_eps: float = 0.02  # progress: the episode's return so far rising above its best by at least this
    box: tuple[float, ...] = (0.3, -0.35, 0.0, 0.7, 0.28, 0.35)  # safe tcp region: (x, y, z) low, then high

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"operator mode must be one of {MODES}, got {self.mode!r}")
        if self.segment_steps < 1 or self.stall_steps < 1:
            raise ValueError(f"segment_steps and stall_steps must be positive, got {self.segment_steps}, "
                             f"{self.stall_steps}")
        if len(self.box) != 6 or not all(lo < hi for lo, hi in zip(self.box[:3], self.box[3:])):
            raise ValueError(f"box must be (x, y, z) low then high with low < high, got {self.box}")


class ExpertOperator:
    """The scripted expert of the robot's task as the operator (reads the privileged observation)."""

    def __init__(self, spec: RobotSpec, config: OperatorConfig):
        self.config = config
        self.expert = make_expert(spec)
        self.held_dist = PickPlaceExpert.held_dist
        self.lift_z = 2.5 * BinGeometry.cube_half
        self.low, self.high = np.array(config.box[:3]), np.array(config.box[3:])
        self.pick_place = spec.task == "pick_place"
        self.reset()

    def reset(self) -> None:
        """A new episode: the policy drives, counters at zero."""
        self.expert.reset()
        self.left = 0  # operator steps left in the current segment (0: the policy drives)
        self.best = -np.inf
        self.ret = 0.0  # the episode's return so far
        self.since_progress = 0
        self.carrying = False
        self.steps = self.operator_steps = self.takeovers = 0
        self.last_reason = ""

    @property
    def rate(self) -> float:
        return self.operator_steps / max(self.steps, 1)

    def _trigger(self, obs: dict[str, np.ndarray]) -> str:
        """Why the operator takes over now ("" if it does not)."""
        p = np.asarray(obs["privileged"], dtype=np.float64)
        tcp = p[:3]
        if np.any(tcp < self.low) or np.any(tcp > self.high):
            return "unsafe"
        if self.pick_place:
            obj = p[8:11]
            held = bool(np.linalg.norm(obj - tcp) < self.held_dist and obj[2] > self.lift_z)
            dropped = self.carrying and not held and np.linalg.norm(obj - tcp) > self.held_dist
            self.carrying = held
            if dropped:
                return "dropped"
        if self.since_progress >= self.config.stall_steps:
            return "stalled"
        return ""

    def act(self, obs: dict[str, np.ndarray], policy_action: np.ndarray) -> tuple[np.ndarray, bool]:
        """The action to execute and whether the operator chose it."""
        self.steps += 1
        mode = self.config.mode
        if mode == "off":
            return policy_action, False
        if mode == "gate" and self.left == 0:
            reason = self._trigger(obs)
            if not reason:
                if self.config.watch:
                    self.expert(obs)  # its phase follows what the policy achieves; the action is not used
                return policy_action, False
            self.last_reason = reason
            self.takeovers += 1
            if hasattr(self.expert, "resync"):
                self.expert.resync(obs)
            self.left = self.config.segment_steps
        self.operator_steps += 1
        if mode == "gate":
            self.left -= 1
            if self.left == 0:  # handing back: the policy gets a fresh stall allowance
                self.since_progress, self.best, self.carrying = 0, -np.inf, False
        return np.asarray(self.expert(obs), np.float32), True

    def observe(self, reward: float) -> None:
        """The step's reward: progress bookkeeping for the stall trigger."""
        self.ret += float(reward)
        if self.ret > self.best + self.config.stall_eps:
            self.best, self.since_progress = self.ret, 0
        else:
            self.since_progress += 1
