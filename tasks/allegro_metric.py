"""The evaluation metric of ``allegro_rotate`` (``AllegroRotate.eval_tracker()``, the trainer's ``eval/*``):
``rotation_rate``, ``time_to_fall`` and ``rotate_reward`` over each env's first episode."""

from __future__ import annotations

import numpy as np

from tasks import base


class RotationTracker:
    """The evaluation metric over each env's first episode while a caller steps the task (``step`` /
    ``result`` like ``walking_metric.WalkingTracker``): ``rotation_rate`` (rad/s, mean object yaw rate over the
    episode's steps), ``time_to_fall`` (fraction of the episode before a fall, 1 without one),
    ``rotate_reward`` (mean per-step rotation term); ``rotation_rate_se``: the standard error of
    ``rotation_rate`` over the episodes (the per-episode rates' std / sqrt(episodes)), what ranks two
    evaluations; ``rotation_episode`` (rad/s): the yaw each episode turned over the whole time limit, its steps
    after a fall counting 0 (``rotation_rate`` averages over the steps before the fall, so an object flung off the
    palm counts at the speed it was flung with), final once ``done``. ``stepper``: what ``step`` steps (the task,
    or a ``<task>_hist`` variant wrapping it); the metric's inputs are read from ``task``."""

    LOGGED = ("rotation_rate", "rotation_rate_se", "rotation_episode", "time_to_fall", "rotate_reward")

    def __init__(self, task, stepper=None):
        self._task, self._stepper = task, stepper if stepper is not None else task
        m = task.num_envs
        self.active = np.ones(m, dtype=bool)
        self._steps = np.zeros(m)
        self._fall_at = np.full(m, np.nan)
        self._angvel = np.zeros(m)
        self._rotate = np.zeros(m)

    @property
    def done(self) -> bool:
        return not self.active.any()

    def step(self, action: np.ndarray) -> base.StepOut:
        out = self._stepper.step(action)
        a = self.active
        self._steps += a
        self._angvel += np.where(a, self._task.object_angvel_z, 0.0)
        self._rotate += np.where(a, out.reward_terms["rotate"], 0.0)
        self._fall_at = np.where(a & out.terminated, self._steps, self._fall_at)
        self.active = a & ~(out.terminated | out.truncated)
        return out

    def result(self) -> dict[str, float]:
        steps = np.maximum(self._steps, 1)
        limit = self._task.spec.episode_length
        ttf = np.where(np.isnan(self._fall_at), 1.0, np.nan_to_num(self._fall_at) / limit)
        rates = self._angvel / steps
        se = float(np.std(rates, ddof=1) / np.sqrt(rates.size)) if rates.size > 1 else 0.0
        return {"rotation_rate": float(np.mean(rates)), "rotation_rate_se": se,
                "rotation_episode": float(np.mean(self._angvel) / limit), "time_to_fall": float(np.mean(ttf)),
                "rotate_reward": float(np.mean(self._rotate / steps))}
