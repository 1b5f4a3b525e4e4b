"""The walking criterion (``metrics.WALKING``: planar tracking <= 0.25 m/s, yaw-rate error <= 0.3 rad/s,
falls <= 2%) on hand-made episodes: a scripted task whose commands, measured velocities and falls are set
by hand, measured by ``tasks.walking_metric.walking_metric`` and judged by the criterion."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tasks import base
from tasks.walking_metric import walking_metric
from unilab_jax.metrics import WALKING, WalkingCriterion

M = 50  # episodes: one fall is 2% (allowed), two are 4%


@dataclasses.dataclass(frozen=True)
class _EpisodesConfig:
    planar_error: float = 0.0  # |v_xy_cmd - v_xy| of every env on every step
    yaw_error: float = 0.0  # |wz_cmd - wz|
    falls: int = 0  # envs 0 .. falls-1 terminate on their 2nd step


class _Episodes(base.Task):
    """``M`` envs with command (0.6, 0, 0.5); the measured velocity is off by ``planar_error`` along y and
    by ``yaw_error`` in yaw rate; the first ``falls`` envs terminate on step 2, the rest are truncated on
    step 10."""

    def __init__(self, config, num_envs, seed):
        super().__init__(config, num_envs, seed)
        self.spec = base.TaskSpec("walking_episodes", obs_dim=1, critic_obs_dim=1, action_dim=1, episode_length=10,
                                  ctrl_dt=0.02, reward_terms=())
        self.command = np.tile([0.6, 0.0, 0.5], (num_envs, 1))
        self._vel = self.command + [0.0, config.planar_error, -config.yaw_error]
        self.t = 0

    def reset(self):
        return np.zeros((self.num_envs, 1), np.float32), np.zeros((self.num_envs, 1), np.float32)

    def step(self, action):
        self.t += 1
        term = (np.arange(self.num_envs) < self.config.falls) & (self.t == 2)
        trunc = np.full(self.num_envs, self.t == self.spec.episode_length)
        obs = np.zeros((self.num_envs, 1), np.float32)
        z = np.zeros(self.num_envs, np.float32)
        return base.StepOut(obs, obs, obs, obs, z, term, trunc, {})

    def base_velocity(self):
        return self._vel.copy()


@pytest.fixture(scope="module")
def episodes():
    base.register("walking_episodes", _Episodes, _EpisodesConfig)
    yield lambda **over: walking_metric("walking_episodes", None, lambda w, obs: np.zeros((obs.shape[0], 1)),
                                        num_envs=M, overrides=over)
    base._REGISTRY.pop("walking_episodes", None)


@pytest.mark.parametrize(("over", "walks"), [
    ({}, True),                                               # perfect tracking, no falls
    ({"planar_error": 0.2, "yaw_error": 0.25, "falls": 1}, True),  # inside every bound, 1 fall in 50 = 2%
    ({"planar_error": 0.2, "yaw_error": 0.4}, False),          # walks straight but does not turn
    ({"planar_error": 0.3}, False),                            # too slow / off course
    ({"falls": 2}, False),                                     # 4% falls
])
def test_criterion_on_hand_made_episodes(episodes, over, walks):
    r = episodes(**over)
    assert r["tracking_error"] == pytest.approx(over.get("planar_error", 0.0))
    assert r["yaw_rate_error"] == pytest.approx(over.get("yaw_error", 0.0))
    assert r["fall_rate"] == pytest.approx(over.get("falls", 0) / M)
    assert WALKING.met(r) is walks


def test_criterion_bounds_are_inclusive_and_missing_numbers_fail():
    edge = {"tracking_error": 0.25, "yaw_rate_error": 0.3, "fall_rate": 0.02}
    assert WALKING.met(edge)
    for k in WalkingCriterion.KEYS:
        assert not WALKING.met({**edge, k: edge[k] + 1e-6})
        assert not WALKING.met({**edge, k: math.nan})
        assert not WALKING.met({key: v for key, v in edge.items() if key != k})
    # The trainer's and MJX loop's evaluation rows carry the numbers under "eval/".
    assert WALKING.met({f"eval/{k}": v for k, v in edge.items()}, prefix="eval/")
    assert not WALKING.met(edge, prefix="eval/")
    # A policy that stands still: errors equal the commanded speed / yaw rate (Go1: ~0.5 m/s, ~0.4 rad/s).
    assert not WALKING.met({"tracking_error": 0.5, "yaw_rate_error": 0.4, "fall_rate": 0.0})
