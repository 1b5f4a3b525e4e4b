"""``gym:ENV_ID`` tasks (tasks/gym_env.py) against the task contract, checked step by step against the
Gymnasium environment itself; errors for ids and spaces the tasks cannot drive (as flags:
tests/test_experiments.py)."""

from __future__ import annotations

import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

import tasks
from unilab_jax.config import ConfigError

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
M = 3


def _reference(seed: int, i: int):
    """Environment ``i`` of a task seeded ``seed``, made and reset as the task does."""
    env = gym.make("Pendulum-v1")
    obs, _ = env.reset(seed=int(np.random.SeedSequence(seed).generate_state(M)[i]))
    return env, obs


def test_pendulum_contract_rescaling_auto_reset_and_truncation():
    task = tasks.make("gym:Pendulum-v1", num_envs=M, seed=7)
    s = task.spec
    assert (s.name, s.obs_dim, s.critic_obs_dim, s.action_dim) == ("gym:Pendulum-v1", 3, 3, 1)
    assert (s.episode_length, s.ctrl_dt, s.reward_terms) == (200, 0.05, ("reward",))
    obs, cobs = task.reset()
    assert obs.shape == (M, 3) and obs.dtype == np.float32 and np.array_equal(obs, cobs)
    assert len({tuple(row) for row in obs}) == M  # each env its own seed
    refs = [_reference(7, i) for i in range(M)]
    np.testing.assert_allclose(obs, [o for _, o in refs], rtol=1e-6)
    # Actions in [-1, 1] map onto Pendulum's torque bounds [-2, 2]; beyond them they are clipped, NaN is 0.
    actions = np.array([[0.5], [1.7], [np.nan]], np.float32)
    torques = [1.0, 2.0, 0.0]
    for t in range(1, 201):
        out = task.step(actions)
        expect = [env.step(np.array([u], np.float32)) for (env, _), u in zip(refs, torques)]
        for x in (out.obs, out.critic_obs, out.next_obs, out.next_critic_obs, out.reward):
            assert x.dtype == np.float32 and x.shape[0] == M
        np.testing.assert_allclose(out.next_obs, [e[0] for e in expect], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(out.reward, [e[1] for e in expect], rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(out.reward_terms["reward"], out.reward)
        assert not out.terminated.any()
        assert out.truncated.all() == (t == 200) and out.truncated.any() == (t == 200)
        if t < 200:
            np.testing.assert_array_equal(out.obs, out.next_obs)
    # At the time limit: next_obs is the final state, obs the reset that follows (the same env's next reset).
    assert not np.allclose(out.obs, out.next_obs)
    np.testing.assert_allclose(out.obs, [env.reset()[0] for env, _ in refs], rtol=1e-6)
    again = task.step(actions)
    assert not again.truncated.any() and not again.terminated.any()
    task.close()


def test_termination_stays_apart_from_truncation():
    # Hopper falls under random actions within a few dozen steps: terminated, with the fallen state as next_obs.
    task = tasks.make("gym:Hopper-v5", num_envs=4, seed=0)
    assert task.spec.episode_length == 1000 and task.spec.obs_dim == 11 and task.spec.action_dim == 3
    task.reset()
    rng = np.random.default_rng(0)
    ended = np.zeros(4, bool)
    for _ in range(300):
        out = task.step(rng.uniform(-1, 1, (4, 3)).astype(np.float32))
        assert not out.truncated.any()
        done = out.terminated
        for i in np.flatnonzero(done):  # reset after the fall: a fresh start, not the fallen state
            assert not np.allclose(out.obs[i], out.next_obs[i])
        np.testing.assert_array_equal(out.obs[~done], out.next_obs[~done])
        ended |= done
    assert ended.all()
    task.close()


def test_mujoco_envs_render_from_a_copy_of_their_state():
    task = tasks.make("gym:HalfCheetah-v5", num_envs=2, seed=0)
    task.reset()
    rng = np.random.default_rng(0)
    for _ in range(5):
        task.step(rng.uniform(-1, 1, (2, 6)).astype(np.float32))
    inner = task.envs.envs[1].unwrapped
    qpos = inner.data.qpos.copy()
    model, view = task.render_scene(1)
    assert model is inner.model and view is not inner.data
    np.testing.assert_array_equal(view.qpos, qpos)
    np.testing.assert_array_equal(inner.data.qpos, qpos)  # the simulation is untouched
    torso = model.body("torso").id
    assert view.xpos[torso, 0] == pytest.approx(qpos[0] + model.body_pos[torso, 0])  # kinematics computed
    task.close()
    with pytest.raises(NotImplementedError, match="not a MuJoCo environment"):
        tasks.make("gym:Pendulum-v1", num_envs=1).render_scene(0)


def test_episode_length_override_sets_the_time_limit():
    task = tasks.make("gym:Pendulum-v1", num_envs=2, seed=0, overrides={"episode_length": 5})
    assert task.spec.episode_length == 5
    task.reset()
    flags = [task.step(np.zeros((2, 1), np.float32)).truncated.all() for _ in range(10)]
    assert flags == [False] * 4 + [True] + [False] * 4 + [True]
    task.close()
    with pytest.raises(ConfigError, match="episode_length must be at least 1"):
        tasks.make("gym:Pendulum-v1", num_envs=1, overrides={"episode_length": 0})


@pytest.mark.parametrize("name,message", [
    ("gym:NoSuchEnv-v0", "cannot be made"),
    ("gym:CartPole-v1", "action space Discrete(2) is not a Box"),
    ("mars_rover", "or gym:ENV_ID"),
])
def test_unknown_ids_and_non_box_spaces_are_errors(name, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        tasks.default_config(name)


def test_gym_task_in_a_worker_imports_no_jax():
    code = ("import sys, numpy as np, tasks; t = tasks.make('gym:Pendulum-v1', 2, 0); t.reset(); "
            "t.step(np.zeros((2, 1), np.float32)); print('jax' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "False"
