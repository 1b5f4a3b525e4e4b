"""Scripted expert policies (state-based: they read the privileged observation).

``expert = make_expert(spec)``; ``expert.reset()`` at each episode start; ``action = expert(obs)``
returns float32 ``[7]`` in [-1, 1]. Privileged layout (see ``robots.sim``): tcp position (3),
tcp quaternion (4), gripper opening (1), task state (``robots.manipulation``).

``evaluate_expert(task, arm, episodes)`` measures an expert's success rate in-process.

Each expert is a small phase machine over target tcp poses; translation and rotation commands are
proportional to the remaining error, clipped to one step's maximum.
"""

from __future__ import annotations

import math
import time

import numpy as np

from unilab_jax.robots import ik, scenes
from unilab_jax.robots.interface import RobotSpec
from unilab_jax.robots.manipulation import PegGeometry, object_yaw
from unilab_jax.robots.sim import SimConfig, SimRobot

OPEN, CLOSED = -1.0, 1.0


def move_action(tcp: np.ndarray, quat: np.ndarray, target: np.ndarray, target_quat: np.ndarray, grip: float,
                spec: RobotSpec, max_speed: float = 1.0) -> np.ndarray:
    """[7] action driving the tcp (pos [3], quat [4]) towards (target [3], target_quat [4]).

    ``max_speed`` in (0, 1] caps the translation command (fraction of ``spec.max_delta_pos`` per step).
    """
    dpos = np.clip((target - tcp) / spec.max_delta_pos, -max_speed, max_speed)
    drot = np.clip(ik.quat_error(target_quat, quat) / spec.max_delta_rot, -1.0, 1.0)
    return np.concatenate([dpos, drot, [grip]]).astype(np.float32)


def grasp_quat(yaw: float) -> np.ndarray:
    """The pointing-down tcp orientation turned by ``yaw`` about world z: quaternion [4]."""
    return ik.quat_mul(ik.quat_from_rotvec([0.0, 0.0, yaw]), np.array(scenes.HOME_TCP_QUAT))


def square_yaw(yaw: float) -> float:
    """A square's yaw folded into [-pi/4, pi/4] (its four sides are equivalent)."""
    return float((yaw + np.pi / 4) % (np.pi / 2) - np.pi / 4)


def _split(obs: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    p = np.asarray(obs["privileged"], dtype=np.float64)
    return p[:3], p[3:7], float(p[7]), p[8:]


class PickPlaceExpert:
    """Above the cube (yaw aligned) -> down -> close -> lift -> over the bin -> open. If the cube is not
    between the fingers while carrying it (a missed or slipped grasp), it starts over from above the cube."""

    hover = 0.1  # above the cube while aligning
    carry_z = 0.16
    release_z = 0.11
    grasp_steps = 5
    held_dist = 0.03  # the cube counts as held within this distance of the tcp
    held_opening = 0.85  # ... and with the gripper's opening (1: fully open) below this (fingers on the cube)

    def __init__(self, spec: RobotSpec):
        self.spec = spec
        self.reset()

    def reset(self) -> None:
        self.phase = "approach"
        self.count = 0
        self.yaw = None

    def resync(self, obs: dict[str, np.ndarray]) -> None:
        """Taking over from someone else mid-episode: the phase the state shows. A cube between closed fingers
        is carried on (``lift``); otherwise a descent or grasp already above the cube goes on, anything else
        starts from above the cube (an earlier phase would open the gripper over a carried cube)."""
        tcp, _, opening, state = _split(obs)
        obj = state[:3]
        if np.linalg.norm(obj - tcp) < self.held_dist and opening < self.held_opening:
            if self.phase not in ("lift", "transfer", "lower"):
                self.phase = "lift"
        elif not (self.phase in ("descend", "grasp") and np.linalg.norm(tcp[:2] - obj[:2]) < 0.01):
            self.phase, self.yaw = "approach", None

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        tcp, quat, _, state = _split(obs)
        obj, bin_pos = state[:3], state[7:10]
        if self.phase in ("lift", "transfer", "lower") and np.linalg.norm(obj - tcp) > self.held_dist:
            self.phase, self.yaw = "approach", None
        if self.yaw is None:
            self.yaw = square_yaw(object_yaw(state))
        q = grasp_quat(self.yaw)
        above = obj + [0.0, 0.0, self.hover]
        if self.phase == "approach":
            # Descend once aligned over the cube (position in the plane, yaw), at any height: a switch at the
            # point above the cube would meet the approach's own small corrections there, and a cloned
            # policy averaging the two stalls just short of the point (approach up, descent down).
            if np.linalg.norm(tcp[:2] - obj[:2]) < 0.01 and np.linalg.norm(ik.quat_error(q, quat)) < 0.05:
                self.phase = "descend"
            else:
                return move_action(tcp, quat, above, q, OPEN, self.spec)
        if self.phase == "descend":
            if np.linalg.norm(tcp - obj) < 0.006:
                self.phase, self.count = "grasp", 0
            return move_action(tcp, quat, obj, q, OPEN, self.spec, max_speed=0.6)
        if self.phase == "grasp":
            self.count += 1
            if self.count >= self.grasp_steps:
                self.phase = "lift"
            return move_action(tcp, quat, obj, q, CLOSED, self.spec)
        if self.phase == "lift":
            if tcp[2] > self.carry_z - 0.03:
                self.phase = "transfer"
            lift = np.array([tcp[0], tcp[1], self.carry_z])
            return move_action(tcp, quat, lift, q, CLOSED, self.spec, max_speed=0.6)
        if self.phase == "transfer":
            if np.linalg.norm(tcp[:2] - bin_pos[:2]) < 0.015:
                self.phase = "lower"
            over_bin = np.array([bin_pos[0], bin_pos[1], self.carry_z])
            return move_action(tcp, quat, over_bin, q, CLOSED, self.spec, max_speed=0.8)
        release = np.array([bin_pos[0], bin_pos[1], self.release_z])
        if self.phase == "lower":
            if tcp[2] < self.release_z + 0.01:
                self.phase = "release"
            return move_action(tcp, quat, release, q, CLOSED, self.spec)
        return move_action(tcp, quat, release, q, OPEN, self.spec)


class PegInsertionExpert:
    """Tip above the hole (aligned within 1.5 mm) -> straight down, correcting x/y on the way."""

    hover = 0.02
    align_tol = 0.0015
    descend_speed = 0.3

    def __init__(self, spec: RobotSpec, geometry: PegGeometry | None = None):
        self.spec = spec
        self.g = geometry or PegGeometry()
        self.reset()

    def reset(self) -> None:
        self.phase = "align"

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        tcp, quat, _, state = _split(obs)
        tip, hole = state[:3], state[3:6]
        q = grasp_quat(0.0)
        above = hole + [0.0, 0.0, self.hover]
        if self.phase == "align":
            err = above - tip
            if np.max(np.abs(err[:2])) < self.align_tol and abs(err[2]) < 0.005:
                self.phase = "insert"
            return move_action(tcp, quat, tcp + err, q, CLOSED, self.spec)
        bottom = hole - [0.0, 0.0, self.g.depth + 0.01]
        return move_action(tcp, quat, tcp + (bottom - tip), q, CLOSED, self.spec, max_speed=self.descend_speed)


class ReachExpert:
    """Straight over the target, at the current height, gripper open."""

    def __init__(self, spec: RobotSpec):
        self.spec = spec

    def reset(self) -> None:
        pass

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        tcp, quat, _, state = _split(obs)
        return move_action(tcp, quat, np.array([state[0], state[1], tcp[2]]), grasp_quat(0.0), OPEN, self.spec)


EXPERTS = {"pick_place": PickPlaceExpert, "peg_insertion": PegInsertionExpert, "reach": ReachExpert}
PAIRS = (("peg_insertion", "franka"), ("pick_place", "franka"), ("pick_place", "ur5e"), ("peg_insertion", "ur5e"),
         ("reach", "franka"))


def make_expert(spec: RobotSpec) -> PickPlaceExpert | PegInsertionExpert | ReachExpert:
    """The scripted expert of ``spec.task``."""
    if spec.task not in EXPERTS:
        raise ValueError(f"no scripted expert for task {spec.task!r}; available: {sorted(EXPERTS)}")
    return EXPERTS[spec.task](spec)


def evaluate_expert(task: str, arm: str, episodes: int, seed: int = 0) -> dict:
    """Runs the scripted expert in-process (unpaced, no cameras) for ``episodes`` random episodes.

    Returns {task, arm, episodes, success_rate, mean_steps, seconds}.
    """
    robot = SimRobot(SimConfig(arm=arm, task=task, speed=math.inf, cameras=(), reset_seconds=0.0, seed=seed))
    expert = make_expert(robot.spec)
    successes, steps = 0, 0
    t = time.perf_counter()
    for episode in range(episodes):
        obs = robot.reset(seed=seed * 100_000 + episode)
        expert.reset()
        while True:
            result = robot.step(expert(obs))
            obs = result.obs
            if result.terminated or result.truncated:
                break
        successes += result.info["success"]
        steps += result.info["t"]
    robot.close()
    return {"task": task, "arm": arm, "episodes": episodes, "success_rate": successes / episodes,
            "mean_steps": steps / episodes, "seconds": time.perf_counter() - t}
