"""A walking metric for every locomotion task: velocity tracking of a policy, independent of reward scaling.

* ``walking_metric``: runs a deterministic policy on a fresh task and reports velocity-tracking error,
  yaw-rate error and fall rate -- numbers that do not depend on any task's reward scaling
  (``unilab_jax/metrics.py``'s walking criterion judges them).
* ``WalkingTracker``: the same numbers accumulated while a caller steps the task (the trainer's periodic
  evaluation uses it on the episodes it already runs); ``is_locomotion`` says whether a task can be measured.

The task must expose ``task.command [M, 3]`` (vx, vy, yaw rate asked for) and ``task.base_velocity() [M, 3]``
(the measured body-frame vx, vy and yaw rate); Go1, Go2 and G1 do.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from tasks import base


def walking_metric(task_name: str, weights: Any, act_fn: Callable[[Any, np.ndarray], np.ndarray],
                   num_envs: int = 16, steps: int | None = None, seconds: float | None = None, seed: int = 0,
                   overrides: Mapping[str, Any] | None = None) -> dict[str, float]:
    """Velocity tracking of a deterministic policy, independent of any reward scaling.

    Runs ``act_fn(weights, obs) -> action [M, action_dim]`` on a fresh ``task_name`` instance with
    ``num_envs`` envs; each env's *first* episode is evaluated for at most ``steps`` control steps
    (``seconds / ctrl_dt`` if given instead; default one episode length). The task must expose
    ``command [M, 3]`` and ``base_velocity() [M, 3]`` (body-frame vx, vy, yaw rate). Returns:

    * ``tracking_error``: mean over evaluated steps of |v_xy_cmd - v_xy| (m/s, body frame);
    * ``yaw_rate_error``: mean |wz_cmd - wz| (rad/s);
    * ``command_speed`` / ``command_yaw_rate``: mean |v_xy_cmd| and |wz_cmd| over the same steps (the
      errors of a policy that stands still);
    * ``fall_rate``: fraction of the ``num_envs`` episodes that terminated (not truncated) in the window;
    * ``evaluated_steps`` and ``episodes``.

    A step counts when its env is still in its first episode and did not end on that step (an ended env's
    state is already the next episode's reset); the command compared is the one in force during the step.
    """
    import tasks

    task = tasks.make(task_name, num_envs, seed=seed, overrides=overrides)
    try:
        if steps is None:
            steps = round(seconds / task.spec.ctrl_dt) if seconds is not None else task.spec.episode_length
        if steps <= 0:
            raise ValueError(f"steps must be positive, got {steps}")
        tracker = WalkingTracker(task)
        obs, _ = task.reset()
        for _ in range(steps):
            out = tracker.step(np.asarray(act_fn(weights, obs), dtype=np.float32))
            obs = out.obs
            if tracker.done:
                break
    finally:
        task.close()
    return tracker.result()


class WalkingTracker:
    """Accumulates ``walking_metric``'s numbers over each env's first episode while a caller steps the task
    (the trainer's periodic evaluation uses it on the episodes it already runs).

    ``step(action)`` steps the task and returns its ``StepOut``; ``result()`` gives the metric dictionary, of
    which the trainer logs the ``LOGGED`` entries.
    """

    LOGGED = ("tracking_error", "yaw_rate_error", "fall_rate")

    def __init__(self, task: Any):
        if not is_locomotion(task):
            raise TypeError(f"task {task.spec.name!r} exposes no command / base_velocity(): not a locomotion task")
        self._task = task
        m = task.num_envs
        self.active = np.ones(m, dtype=bool)
        self._fell = np.zeros(m, dtype=bool)
        self._sums = np.zeros(4)  # tracking error, yaw error, command speed, command yaw rate
        self._count = 0

    @property
    def done(self) -> bool:
        return not self.active.any()

    def step(self, action: np.ndarray) -> base.StepOut:
        cmd = np.array(self._task.command, dtype=np.float64, copy=True)
        out = self._task.step(action)
        ended = out.terminated | out.truncated
        self._fell |= self.active & out.terminated
        ok = self.active & ~ended
        if ok.any():
            vel = self._task.base_velocity()[ok]
            c = cmd[ok]
            self._sums += [np.linalg.norm(c[:, :2] - vel[:, :2], axis=1).sum(), np.abs(c[:, 2] - vel[:, 2]).sum(),
                           np.linalg.norm(c[:, :2], axis=1).sum(), np.abs(c[:, 2]).sum()]
            self._count += int(ok.sum())
        self.active &= ~ended
        return out

    def result(self) -> dict[str, float]:
        mean = self._sums / self._count if self._count else np.full(4, np.nan)
        return {
            "tracking_error": float(mean[0]), "yaw_rate_error": float(mean[1]),
            "command_speed": float(mean[2]), "command_yaw_rate": float(mean[3]),
            "fall_rate": float(self._fell.mean()), "evaluated_steps": self._count, "episodes": len(self._fell),
        }


def is_locomotion(task: Any) -> bool:
    """Whether ``task`` exposes what the walking metric reads (``command`` and ``base_velocity()``)."""
    return hasattr(task, "command") and callable(getattr(task, "base_velocity", None))
