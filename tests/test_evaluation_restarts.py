"""``run_episodes`` on a robot task whose step is interrupted: after a lost robot every env was reset, so the
evaluation's episodes start over, at most ``MAX_EVAL_RESTARTS`` times; a protective stop (the robot refused the
policy's command) ends them there, the stopped ones failed."""

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

    def __init__(self, interrupt_at: set[int], stopped: tuple[int, ...] = ()):
        self.calls, self.t, self.interrupt_at, self.stopped = 0, 0, interrupt_at, stopped

    def reset(self):
        self.t = 0
        return np.zeros((2, 1), np.float32), np.zeros((2, 1), np.float32)

    def step(self, action):
        self.calls += 1
        if self.calls in self.interrupt_at:
            obs, critic = self.reset()
            raise StepInterrupted("robot lost" if not self.stopped else "protective stop", obs, critic, self.stopped)
        self.t += 1
        done = np.full(2, self.t == 3)
        obs, zero = np.full((2, 1), self.t, np.float32), np.zeros((2, 1), np.float32)
        return StepOut(obs=obs, critic_obs=zero, next_obs=obs, next_critic_obs=zero, reward=np.ones(2, np.float32),
                       terminated=done, truncated=np.zeros(2, bool), reward_terms={})


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


def test_a_protective_stop_ends_the_evaluation_s_episodes_as_failed():
    task = _Robots({2}, stopped=(1,))
    _, stats = run_episodes(task, lambda obs: np.zeros((2, 7), np.float32))
    assert task.calls == 2 and "restarts" not in stats  # not started over: the policy's commands stopped the robot
    assert stats["protective_stops"] == 1 and stats["success_rate"] == 0.0
    assert stats["return"] == 1.0 and stats["episode_length"] == 1.0  # the step before the stop
