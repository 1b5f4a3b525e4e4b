"""``run_episodes`` on a robot task whose step is interrupted: after a lost robot every env was reset, so the
evaluation's episodes start over, at most ``MAX_EVAL_RESTARTS`` times; a protective stop (the robot refused the
policy's command) ends only that robot's episode, failed (the task's ``stop_ends_episode``, which it sets)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tasks.base import StepInterrupted, StepOut
from unilab_jax.training.evaluation import MAX_EVAL_RESTARTS, run_episodes


class _Robots:
    """Two envs whose episodes succeed at their 3rd step; the steps listed in ``interrupt_at`` are interrupted."""

    num_envs = 2
    spec = SimpleNamespace(name="robot_stub", episode_length=10, success_on_termination=True, obs_dim=1,
                           reward_terms=())

    def __init__(self, interrupt_at: set[int], stop_at: int = 0):
        self.calls, self.t, self.interrupt_at, self.stop_at = 0, 0, interrupt_at, stop_at
        self.stop_ends_episode = False

    def reset(self):
        self.t = 0
        return np.zeros((2, 1), np.float32), np.zeros((2, 1), np.float32)

    def step(self, action):
        self.calls += 1
        if self.calls in self.interrupt_at:
            obs, critic = self.reset()
            raise StepInterrupted("robot lost", obs, critic)
        self.t += 1
        done = np.full(2, self.t == 3)
        stopped = np.array([False, self.calls == self.stop_at])  # env 1's robot stops (as RobotTask with the flag)
        obs, zero = np.full((2, 1), self.t, np.float32), np.zeros((2, 1), np.float32)
        return StepOut(obs=obs, critic_obs=zero, next_obs=obs, next_critic_obs=zero,
                       reward=np.where(stopped, 0.0, 1.0).astype(np.float32), terminated=done & ~stopped,
                       truncated=stopped, reward_terms={},
                       extras={"protective_stop": stopped} if self.stop_ends_episode else None)


def test_an_interrupted_evaluation_starts_its_episodes_over():
    task = _Robots({2})
    _, stats = run_episodes(task, lambda obs: np.zeros((2, 7), np.float32))
    assert stats["restarts"] == 1 and stats["success_rate"] == 1.0
    assert stats["return"] == 3.0 and stats["episode_length"] == 3.0  # the interrupted step's episode is not counted


def test_an_evaluation_interrupted_too_often_raises():
    task = _Robots(set(range(1, 100)))
    with pytest.raises(StepInterrupted):
        run_episodes(task, lambda obs: np.zeros((2, 7), np.float32))
    assert task.calls == MAX_EVAL_RESTARTS + 1


def test_a_protective_stop_ends_that_robot_s_episode_only():
    task = _Robots(set(), stop_at=2)
    _, stats = run_episodes(task, lambda obs: np.zeros((2, 7), np.float32))
    assert task.calls == 3 and "restarts" not in stats  # env 0 went on to its success at step 3
    assert stats["protective_stops"] == 1 and stats["success_rate"] == 0.5
    assert stats["return"] == (3.0 + 1.0) / 2 and stats["episode_length"] == (3 + 2) / 2
    assert task.stop_ends_episode is False  # set while evaluating only
