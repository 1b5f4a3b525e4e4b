"""The walking metric: exact bookkeeping on a scripted probe task, then standing-still policies on Go1/Go2."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import tasks
from tasks import base
from tasks.walking_metric import walking_metric


@dataclasses.dataclass(frozen=True)
class _ProbeConfig:
    pass


class _Probe(base.Task):
    """3 envs with fixed commands and measured velocities. Env 0 terminates on its 3rd step, env 1 is
    truncated on its 4th, env 2 never ends; an ended env gets a wild command (as a reset would) that the
    metric must not count."""

    def __init__(self, config, num_envs, seed):
        super().__init__(config, num_envs, seed)
        self.spec = base.TaskSpec("walking_probe", obs_dim=2, critic_obs_dim=2, action_dim=1, episode_length=100,
                                  ctrl_dt=0.5, reward_terms=())
        self.command = np.array([[1.0, 0.0, 0.5], [0.0, 2.0, 0.0], [0.3, 0.4, -1.0]])
        self._vel = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.3, 0.4, -1.0]])
        self.t = 0
        self.actions = []

    def reset(self):
        return np.zeros((3, 2), np.float32), np.zeros((3, 2), np.float32)

    def step(self, action):
        self.actions.append(np.array(action))
        self.t += 1
        term = np.array([self.t == 3, False, False])
        trunc = np.array([False, self.t == 4, False])
        self.command[term | trunc] = 9.0
        obs = np.full((3, 2), self.t, np.float32)
        z = np.zeros(3, np.float32)
        return base.StepOut(obs, obs, obs, obs, z, term, trunc, {})

    def base_velocity(self):
        return self._vel.copy()


@pytest.fixture
def probe():
    made = []

    def factory(config, num_envs, seed):
        made.append(_Probe(config, num_envs, seed))
        return made[-1]

    base.register("walking_probe", factory, _ProbeConfig)
    yield made
    base._REGISTRY.pop("walking_probe", None)  # keep the registry as the other tests expect it


def test_metric_bookkeeping_on_probe(probe):
    act = lambda w, obs: np.full((obs.shape[0], 1), w, np.float32)
    r = walking_metric("walking_probe", 0.25, act, num_envs=3, steps=5)
    # counted steps: env 0 steps 1-2 (ends on 3), env 1 steps 1-3 (ends on 4), env 2 steps 1-5 -> 10
    assert r["evaluated_steps"] == 10 and r["episodes"] == 3
    assert r["tracking_error"] == pytest.approx((2 * 1.0 + 3 * 1.0 + 5 * 0.0) / 10)
    assert r["yaw_rate_error"] == pytest.approx((2 * 0.5 + 3 * 1.0 + 5 * 0.0) / 10)
    assert r["command_speed"] == pytest.approx((2 * 1.0 + 3 * 2.0 + 5 * 0.5) / 10)
    assert r["command_yaw_rate"] == pytest.approx((2 * 0.5 + 3 * 0.0 + 5 * 1.0) / 10)
    assert r["fall_rate"] == pytest.approx(1 / 3)  # the truncation is not a fall
    np.testing.assert_array_equal(probe[-1].actions[0], np.full((3, 1), 0.25))  # weights reach act_fn
    # `seconds` is converted with the task's ctrl_dt (0.5 s): 2.5 s = 5 steps
    assert walking_metric("walking_probe", 0.0, act, num_envs=3, seconds=2.5) == r


def test_metric_rejects_non_locomotion_tasks():
    zero = lambda w, obs: np.zeros((obs.shape[0], 1), np.float32)
    with pytest.raises(TypeError, match="base_velocity"):
        walking_metric("cartpole_balance", None, zero, num_envs=2, steps=3)


def test_go1_standing_still_tracks_nothing():
    """A zero-action Go1 stands (or falls): its tracking error is about the commanded speed."""
    zero = lambda w, obs: np.zeros((obs.shape[0], 12), np.float32)
    r = walking_metric("go1_joystick_flat", None, zero, num_envs=16, steps=100, seed=0)
    assert 0.3 < r["command_speed"] < 1.7 and 0.1 < r["command_yaw_rate"] < 1.2
    assert abs(r["tracking_error"] - r["command_speed"]) < 0.15
    assert abs(r["yaw_rate_error"] - r["command_yaw_rate"]) < 0.15
    assert 0.0 <= r["fall_rate"] <= 1.0 and (r["fall_rate"] * 16).is_integer()
    assert 0.5 * 16 * 100 < r["evaluated_steps"] <= 16 * 100
    again = walking_metric("go1_joystick_flat", None, zero, num_envs=16, steps=100, seed=0)
    assert again == r  # a fresh task with the same seed: the same numbers


def test_go2_task_feeds_the_metric():
    zero = lambda w, obs: np.zeros((obs.shape[0], 12), np.float32)
    r = walking_metric("go2_joystick_flat", None, zero, num_envs=8, steps=50, seed=1,
                       overrides={"push_interval_s": 0.0})
    assert abs(r["tracking_error"] - r["command_speed"]) < 0.2 and r["command_speed"] > 0.2
    assert r["evaluated_steps"] > 0 and 0.0 <= r["fall_rate"] <= 1.0
    task = tasks.make("go2_joystick_flat", 2, seed=0)
    task.reset()
    v = task.base_velocity()
    assert v.shape == (2, 3) and task.command.shape == (2, 3)
    np.testing.assert_allclose(v[:, 2], task._s("gyro")[:, 2])
    task.close()
