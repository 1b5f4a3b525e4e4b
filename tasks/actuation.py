"""Actuation randomisation of the legged tasks: per-env action latency in whole control steps.

``delay_actions`` (shim) is the math: a queue of each env's last ``D`` actions, newest first, and a per-env delay
``d in {0, ..., D}`` picks the action the motors get: the policy's action of ``d`` control steps ago (0: this
step's). ``ActionDelay`` holds the queue of a numpy task: ``apply`` once per step, ``reset`` where episodes start
(the queue refills with zero actions, the default pose the servos hold at reset). The observation and rewards keep
the policy's own action (what it knows it sent); only the motor targets lag.

The delay is drawn per env, once, with the task's other domain-randomisation parameters
(``dr_action_delay = (lo, hi)``: ``U{lo, ..., hi}`` control steps; ``(0, 0)`` is off and draws nothing).
Motor strength (a per-motor factor on each servo's PD torque) is each task's ``randomize_model``'s
(``tasks/go1_joystick.py``, ``tasks/walking.py``: ``dr_motor_strength``).
"""

from __future__ import annotations

import numpy as np

from unilab_jax import xp as shim


def delay_actions(queue, action, delay):
    """(applied [M, A], next queue [M, D, A]): the action ``delay [M]`` (int) steps old given ``queue [M, D, A]``
    (the last ``D`` actions, newest first) and this step's ``action [M, A]``."""
    xp = shim.namespace(queue, action)
    stacked = xp.concat([action[:, None], queue], axis=1)
    applied = xp.take_along_axis(stacked, xp.astype(delay, xp.int32)[:, None, None], axis=1)[:, 0]
    return applied, stacked[:, : queue.shape[1]]


def sample_delays(rng: np.random.Generator, bounds: tuple[int, int], num_envs: int) -> np.ndarray | None:
    """[M] per-env delays ``U{lo, ..., hi}`` (None when ``hi`` is 0: off, nothing drawn)."""
    lo, hi = (int(b) for b in bounds)
    if not 0 <= lo <= hi:
        raise ValueError(f"dr_action_delay {bounds} must be 0 <= lo <= hi control steps")
    return rng.integers(lo, hi + 1, size=num_envs) if hi > 0 else None


class ActionDelay:
    """A numpy task's action queue (see the module docstring); ``delays [M]`` int, ``depth`` the queue's length
    (at least the largest delay)."""

    def __init__(self, delays: np.ndarray, depth: int, action_dim: int):
        self.delays = np.asarray(delays, dtype=np.int64).copy()
        if self.delays.size and not 0 <= self.delays.min() <= self.delays.max() <= depth:
            raise ValueError(f"delays must lie in [0, {depth}]")
        self.queue = np.zeros((self.delays.size, depth, action_dim))

    def apply(self, action: np.ndarray) -> np.ndarray:
        """The actions the motors get this step (and this step's ``action [M, A]`` queued)."""
        if not self.queue.shape[1]:
            return action
        applied, self.queue = delay_actions(self.queue, action, self.delays)
        return applied

    def reset(self, idx: np.ndarray) -> None:
        self.queue[idx] = 0.0
