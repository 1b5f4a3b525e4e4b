"""Every registered task honours the Task contract; Go1 specifics checked on a real simulation."""

from __future__ import annotations

import numpy as np
import pytest

import tasks
from tasks import go1_joystick as g
from unilab_jax.config import ConfigError

NUM_ENVS = 6
STEPS = 50


def _actions(task, steps, seed=0):
    rng = np.random.default_rng(seed)
    # Slightly beyond [-1, 1] to exercise the clipping.
    return rng.uniform(-1.2, 1.2, size=(steps, task.num_envs, task.spec.action_dim)).astype(np.float32)


# Built-in tasks only: test modules register deliberately broken toy tasks (e.g. ``toy_nan`` emits NaN to test
# the runtime's masking), and they may be collected before this module.
BUILTIN = [n for n in tasks.names() if tasks.base._REGISTRY[n].factory.__module__.startswith("tasks.")]
# Robot episodes end only on success or at the robot's time limit (100 steps, which the scripted experts
# need: 40-60 steps): a shorter limit lets random actions end episodes within the STEPS of this test.
# The Allegro object rests on the palm, so random actions rarely drop it: its episodes end at a short limit.
ROLLOUT_OVERRIDES = {"robot_pick_place": {"episode_length": 40}, "robot_peg_insertion": {"episode_length": 40},
                     "robot_reach": {"episode_length": 40},
                     "allegro_rotate": {"episode_length": 40}, "allegro_rotate_hist": {"episode_length": 40}}


@pytest.fixture(scope="module", params=BUILTIN)
def rollout(request):
    """(task, reset outputs, list of StepOut) for STEPS random steps of each registered task."""
    task = tasks.make(request.param, NUM_ENVS, seed=0, overrides=ROLLOUT_OVERRIDES.get(request.param))
    first = task.reset()
    outs = [task.step(a) for a in _actions(task, STEPS)]
    yield task, first, outs
    task.close()


def test_spec_and_shapes(rollout):
    task, (obs, cobs), outs = rollout
    s = task.spec
    assert s.name in tasks.names()
    assert obs.shape == (NUM_ENVS, s.obs_dim) and cobs.shape == (NUM_ENVS, s.critic_obs_dim)
    assert obs.dtype == np.float32 and cobs.dtype == np.float32
    assert np.isfinite(obs).all() and np.isfinite(cobs).all()
    for o in outs:
        for x, dim in ((o.obs, s.obs_dim), (o.next_obs, s.obs_dim), (o.critic_obs, s.critic_obs_dim),
                       (o.next_critic_obs, s.critic_obs_dim)):
            assert x.shape == (NUM_ENVS, dim) and x.dtype == np.float32
            assert np.isfinite(x).all()
        assert o.reward.shape == (NUM_ENVS,) and o.reward.dtype == np.float32
        assert np.isfinite(o.reward).all()
        assert o.terminated.dtype == np.bool_ and o.truncated.dtype == np.bool_
        assert not (o.terminated & o.truncated).any()
        assert tuple(o.reward_terms) == s.reward_terms
        for v in o.reward_terms.values():
            assert v.shape == (NUM_ENVS,) and v.dtype == np.float32 and np.isfinite(v).all()
    if s.privileged_dim:
        ext = task.extrinsics
        assert ext.shape == (NUM_ENVS, s.privileged_dim) and ext.dtype == np.float32


def test_auto_reset_replaces_exactly_the_ended_envs(rollout):
    _, _, outs = rollout
    n_ended = 0
    for o in outs:
        ended = o.terminated | o.truncated
        n_ended += int(ended.sum())
        same = (o.obs == o.next_obs).all(axis=1)
        np.testing.assert_array_equal(same, ~ended)
        np.testing.assert_array_equal((o.critic_obs == o.next_critic_obs).all(axis=1), ~ended)
    assert n_ended > 0, "random actions should end some episodes within 50 steps"


@pytest.mark.parametrize("name", tasks.names())
def test_truncation_at_episode_length(name):
    task = tasks.make(name, 4, seed=1, overrides={"episode_length": 3})
    assert task.spec.episode_length == 3
    task.reset()
    age = np.zeros(4, dtype=int)
    zero = np.zeros((4, task.spec.action_dim), np.float32)
    for _ in range(7):
        o = task.step(zero)
        age += 1
        np.testing.assert_array_equal(o.truncated, (age >= 3) & ~o.terminated)
        age[o.terminated | o.truncated] = 0
    task.close()


@pytest.mark.parametrize("name", tasks.names())
def test_same_seed_same_trajectory(name):
    def run(seed):
        task = tasks.make(name, 3, seed=seed)
        o0, _ = task.reset()
        outs = [task.step(a) for a in _actions(task, 15, seed=3)]
        task.close()
        return np.concatenate([o0.ravel()] + [np.concatenate([o.obs.ravel(), o.reward]) for o in outs])

    a, b, c = run(5), run(5), run(6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("name", tasks.names())
def test_unknown_override_raises(name):
    with pytest.raises(ConfigError, match="not_a_key"):
        tasks.make(name, 2, overrides={"not_a_key": 1})
    with pytest.raises(ValueError):
        tasks.make("no_such_task", 2)


# --------------------------------------------------------------------------------------------------
# Go1 on the real simulation
# --------------------------------------------------------------------------------------------------
CLEAN = {"noise_level": 0.0, "domain_randomization": False}


def test_go1_obs_match_simulation_state_and_playground_lag():
    task = tasks.make("go1_joystick_flat", 2, seed=0, overrides=CLEAN)
    obs, cobs = task.reset()
    np.testing.assert_allclose(obs[:, 6:9], [[0, 0, -1]] * 2, atol=1e-6)  # upright: gravity down
    np.testing.assert_allclose(obs[:, 9:21], 0.0, atol=1e-6)  # home pose == default pose
    np.testing.assert_allclose(obs[:, 33:45], 0.0)  # no previous action
    np.testing.assert_allclose(obs[:, 45:48], task.command, rtol=1e-6)
    np.testing.assert_allclose(obs, cobs[:, :48])
    a1 = np.full((2, 12), 0.3, np.float32)
    a2 = np.full((2, 12), -0.2, np.float32)
    task.step(a1)
    cmd = task.command.copy()
    o = task.step(a2)
    assert not (o.terminated | o.truncated).any()
    # Playground builds the observation before updating last_act: step 2 shows action 1.
    np.testing.assert_allclose(o.next_obs[:, 33:45], a1)
    np.testing.assert_allclose(o.next_obs[:, 45:48], cmd, rtol=1e-6)
    np.testing.assert_allclose(o.next_obs[:, 9:21], task.sim.qpos[:, 7:] - task.default_pose, atol=1e-6)
    np.testing.assert_allclose(o.next_obs[:, 21:33], task.sim.qvel[:, 6:], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(o.next_obs[:, 0:3], task._s("local_linvel"), rtol=1e-5, atol=1e-6)
    # action_rate term = -0.01 * dt * |a2 - a1|^2 = -0.01 * 0.02 * 12 * 0.25
    np.testing.assert_allclose(o.reward_terms["action_rate"], -0.01 * 0.02 * 12 * 0.25, rtol=1e-5)
    # The per-term contributions sum to the (pre-clip) reward.
    total = np.sum(np.stack(list(o.reward_terms.values())), axis=0)
    np.testing.assert_allclose(o.reward, np.maximum(total, 0.0), rtol=1e-5, atol=1e-7)
    task.close()


def test_go1_upside_down_terminates_with_penalty():
    task = tasks.make("go1_joystick_flat", 2, seed=0, overrides=CLEAN)
    task.reset()
    qpos, qvel = task.sim.qpos.copy(), np.zeros_like(task.sim.qvel)
    qpos[0, 2] = 0.5
    qpos[0, 3:7] = [0.0, 1.0, 0.0, 0.0]  # 180 deg about x: up-vector points down
    task.sim.set_state(np.arange(2), qpos, qvel)
    o = task.step(np.zeros((2, 12), np.float32))
    assert o.terminated.tolist() == [True, False]
    assert o.reward_terms["termination"][0] == pytest.approx(-1.0 * 0.02)
    assert o.reward_terms["termination"][1] == 0.0
    assert o.reward_terms["orientation"][0] == pytest.approx(0.0, abs=1e-6)  # up-vector xy is 0
    # next_obs is the upside-down successor (gravity along body +z); obs is after the auto-reset.
    np.testing.assert_allclose(o.next_obs[0, 6:9], [0, 0, 1], atol=1e-3)
    np.testing.assert_allclose(o.obs[0, 6:9], [0, 0, -1], atol=1e-3)
    np.testing.assert_allclose(o.obs[0, 33:45], 0.0)  # fresh episode: no previous action
    assert task.steps.tolist() == [0, 1]
    task.close()


def test_go1_unstable_env_is_truncated_not_nan():
    task = tasks.make("go1_joystick_flat", 3, seed=0)
    task.reset()
    qpos, qvel = task.sim.qpos[1:2].copy(), task.sim.qvel[1:2].copy()
    qvel[0, 6:] = 1e11  # MuJoCo's divergence guard fires
    task.sim.set_state(np.array([1]), qpos, qvel)
    o = task.step(np.zeros((3, 12), np.float32))
    assert o.truncated.tolist() == [False, True, False] and not o.terminated.any()
    assert np.isfinite(o.next_obs).all() and np.isfinite(o.reward).all()
    assert task.unstable_count == 1
    task.close()


def test_go1_engines_agree_and_dr_is_exposed():
    rng = np.random.default_rng(2)
    acts = rng.uniform(-1, 1, size=(20, 4, 12)).astype(np.float32)
    res = {}
    for eng in ("rollout", "step"):
        task = tasks.make("go1_joystick_flat", 4, seed=3, overrides={"physics_engine": eng})
        task.reset()
        res[eng] = [task.step(a).next_obs for a in acts]
        ext, dr, layout = task.extrinsics, task.dr, task.extrinsics_layout
        # Each env simulates its own randomised model.
        frictions = [m.geom_friction[task.floor_id, 0] for m in task.sim.models]
        np.testing.assert_allclose(frictions, dr["floor_friction"][:, 0])
        task.close()
    np.testing.assert_allclose(np.array(res["rollout"]), np.array(res["step"]), rtol=1e-4, atol=1e-4)
    lo, hi = g.default_config().dr_floor_friction
    assert ((dr["floor_friction"] >= lo) & (dr["floor_friction"] <= hi)).all()
    assert ext.shape[1] == sum(v.shape[1] for v in dr.values()) == sum(n for _, n in layout)
    assert np.ptp(ext, axis=0).max() > 0  # per-env values differ


def test_go1_sensor_skipping_does_not_change_dynamics():
    acts = np.random.default_rng(4).uniform(-1, 1, size=(10, 3, 12)).astype(np.float32)
    res = []
    for every in (False, True):
        task = tasks.make("go1_joystick_flat", 3, seed=1,
                          overrides={"physics_engine": "step", "sensors_every_substep": every})
        task.reset()
        res.append(np.array([task.step(a).next_critic_obs for a in acts]))
        task.close()
    np.testing.assert_array_equal(res[0], res[1])
