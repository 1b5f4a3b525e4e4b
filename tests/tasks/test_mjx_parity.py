"""The MJX variant of go1_joystick_flat is the CPU task's MDP: same observation and reward for the same state,
physics that tracks MuJoCo's, and the CPU task's end-of-episode contract under ``jax.jit``.

Tolerances (float32 MJX vs float64 MuJoCo):

* sensors, observations and reward terms from the same state (both engines run forward on it): ~1e-6
  relative, checked at rtol 1e-4 / atol 1e-5, except the accelerometer, which depends on the 1-iteration
  Newton solve of the contact problem and differs by up to ~0.04 m/s^2 of ~10 (atol 0.1);
* one control step (5 substeps) from the same state: with (nearly) no joint friction loss, qpos within
  ~3e-7 of MuJoCo's (checked at 1e-5); with the default friction loss, a joint at rest switching the sign
  of its friction force in float32 but not in float64 separates the trajectories (measured 1e-5 to 1e-3,
  checked at 1e-2). Later steps separate the same way at such switches and at foot touch-downs (measured
  ~2e-4 after 2 steps, ~1e-2 after 5). Statistically the two are one MDP: a random policy on 128 envs
  for 300 steps gives the same mean reward per step (CPU 4.5e-4, MJX 4.2e-4 and 4.5e-4 in two runs) and
  termination counts within noise (678 CPU vs 639-643 MJX).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compile_options import FAST_COMPILE

import tasks
from unilab_jax.training.mjx import make_env

M = 8
OPTS = FAST_COMPILE  # less XLA compile time; numerics unchanged
# Noise-free observations (the two engines draw different noise); short episodes. tests/test_mjx_training.py
# uses the same env, so a process running both compiles it once.
OVERRIDES = {"noise_level": 0.0, "episode_length": 20}
ACCEL = slice(48 + 3, 48 + 6)  # accelerometer columns of the critic observation


@pytest.fixture(scope="module")
def env():
    return make_env("go1_joystick_flat", M, OVERRIDES, OPTS)


@pytest.fixture(scope="module")
def forward(env):
    return jax.jit(env.env.forward, compiler_options=OPTS)


def _cpu_task(overrides=None, steps=15, seed=1):
    """A CPU task walked ``steps`` small random steps from reset (feet on and off the floor, air time > 0)."""
    task = tasks.make("go1_joystick_flat", M, seed=seed, overrides={**OVERRIDES, **(overrides or {})})
    task.reset()
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        task.step(rng.uniform(-0.3, 0.3, (M, 12)).astype(np.float32))
    return task, rng


def _edit(fn, *args):
    """``fn(*args)`` under jit: its outputs are uncommitted arrays like ``reset``'s, so the jitted step
    does not compile a second time for states edited in the tests (eager results are committed)."""
    return jax.jit(fn)(*args)


def _mjx_state(env, task):
    """An MJX state with the CPU task's domain randomisation and episode bookkeeping (data set later)."""
    dr = {k: np.asarray(v, np.float32) for k, v in task.dr.items()}
    info = {k: np.asarray(v, bool if v.dtype == bool else np.float32) for k, v in task.info().items()}

    def build(state, dr, info, steps, until):
        return state._replace(model_fields=env.env.model_fields(dr), pose_offset=dr["default_pose_offset"],
                              info=info, steps=steps, steps_until_next_cmd=until)

    return _edit(build, env.reset(jax.random.PRNGKey(0)), dr, info, task.steps.astype(np.int32),
                 task.steps_until_next_cmd.astype(np.int32))


def _f32(x):
    return jnp.asarray(np.asarray(x), jnp.float32)


def test_same_state_gives_same_observation_and_reward(env, forward):
    transition = jax.jit(env.env.transition, compiler_options=OPTS)
    task, rng = _cpu_task({"dr_motor_strength": (0.8, 1.2)})  # every DR parameter in use
    assert env.env.spec == task.spec
    assert {k: v.shape[1] for k, v in task.dr.items()} == env.env.dr_dims
    state = _mjx_state(env, task)
    qpos, qvel = task.sim.qpos.copy(), task.sim.qvel.copy()
    ctrl = task._targets(task.last_act)
    action = rng.uniform(-0.5, 0.5, (M, 12))
    # Both engines run forward on (qpos, qvel, ctrl); then the task's own post-physics code on each.
    data = forward(state.model_fields, _f32(qpos), _f32(qvel), _f32(ctrl))
    task.sim.set_state(np.arange(M), qpos, qvel, ctrl=ctrl)
    sensordata = task.sim.sensordata.copy()
    info_before = {k: np.array(v) for k, v in task.info().items()}
    cpu = task._after_physics(action.copy(), np.zeros(M, bool))
    new_state, out = transition(state, data, _f32(action))  # the step's math, without the auto-reset

    contact = info_before["last_contact"]
    assert contact.any() and not contact.all() and (info_before["feet_air_time"] > 0).any()  # a non-trivial state
    assert not cpu.terminated.any() and not cpu.truncated.any()
    sd = np.asarray(data.sensordata)
    a0 = env.env.sensor_index["accelerometer"][0]
    rest = np.r_[0:a0, a0 + 3 : sd.shape[1]]
    np.testing.assert_allclose(sd[:, rest], sensordata[:, rest], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(sd[:, a0 : a0 + 3], sensordata[:, a0 : a0 + 3], atol=0.1)
    np.testing.assert_allclose(np.asarray(out.next_obs), cpu.next_obs, rtol=1e-4, atol=1e-5)
    cobs, cpu_cobs = np.asarray(out.next_critic_obs), cpu.next_critic_obs
    keep = np.ones(cobs.shape[1], bool)
    keep[ACCEL] = False
    np.testing.assert_allclose(cobs[:, keep], cpu_cobs[:, keep], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(cobs[:, ACCEL], cpu_cobs[:, ACCEL], atol=0.1)
    assert set(out.reward_terms) == set(cpu.reward_terms)
    for k, v in cpu.reward_terms.items():
        np.testing.assert_allclose(np.asarray(out.reward_terms[k]), v, rtol=1e-4, atol=1e-7, err_msg=k)
    np.testing.assert_allclose(np.asarray(out.reward), cpu.reward, rtol=1e-4, atol=1e-7)
    assert (cpu.reward > 0).any()
    np.testing.assert_array_equal(np.asarray(out.terminated), cpu.terminated)
    for k in ("feet_air_time", "swing_peak", "last_act"):
        np.testing.assert_allclose(np.asarray(new_state.info[k]), task.info()[k], rtol=1e-5, atol=1e-6, err_msg=k)
    np.testing.assert_array_equal(np.asarray(new_state.info["last_contact"]), task.last_contact)


@pytest.mark.parametrize("frictionloss,qpos_tol", [(False, 1e-5), (True, 1e-2)])
def test_rollout_tracks_mujoco(env, forward, frictionloss, qpos_tol):
    # "Off" is a 1000x smaller friction loss: exactly 0 would differ (MJX keeps the base model's friction
    # rows, MuJoCo drops rows with zero friction loss; the default range 0.9-1.1 x 0.2 never draws 0).
    overrides = {"dr_motor_strength": (0.8, 1.2)}
    if not frictionloss:
        overrides["dr_frictionloss_scale"] = (1e-3, 1e-3)
    task, rng = _cpu_task(overrides, seed=2)
    state = _mjx_state(env, task)
    qpos, qvel, ctrl = task.sim.qpos.copy(), task.sim.qvel.copy(), task._targets(task.last_act)
    task.sim.set_state(np.arange(M), qpos, qvel, ctrl=ctrl)
    state = _edit(lambda st, d: st._replace(data=d), state,
                  forward(state.model_fields, _f32(qpos), _f32(qvel), _f32(ctrl)))
    action = rng.uniform(-0.5, 0.5, (M, 12)).astype(np.float32)
    cpu = task.step(action)
    state, out = env.step(state, jnp.asarray(action))
    assert not (cpu.terminated | cpu.truncated).any()
    assert not np.asarray(out.terminated | out.truncated).any()
    err = np.abs(np.asarray(state.data.qpos) - task.sim.qpos).max()
    assert err < qpos_tol
    if not frictionloss:  # joint velocities are the most sensitive entries (~1e-2 of a few rad/s)
        np.testing.assert_allclose(np.asarray(out.next_obs), cpu.next_obs, atol=5e-2)
        np.testing.assert_allclose(np.asarray(out.reward), cpu.reward, atol=1e-4)


def test_step_contract_under_jit(env):
    """Shapes and dtypes of the TaskSpec, per-env domain randomisation, time-limit truncation with auto-reset,
    and divergence handling (truncated, zeroed outputs, reset), all through the jitted step."""
    e, spec = env.env, env.env.spec
    state = env.reset(jax.random.PRNGKey(3))
    assert state.obs.shape == (M, spec.obs_dim) and state.critic_obs.shape == (M, spec.critic_obs_dim)
    assert np.unique(np.asarray(state.model_fields["geom_friction"][:, e.floor_id, 0])).size == M
    assert np.unique(np.asarray(state.model_fields["body_mass"][:, e.torso_id])).size == M
    limit = spec.episode_length
    # Env 0 at its last step; env 1 diverged (NaN velocity, as an unstable simulation gives).
    state = _edit(lambda st: st._replace(steps=st.steps.at[0].set(limit - 1),
                                         episode_length=st.episode_length.at[0].set(limit - 1),
                                         data=st.data.replace(qvel=st.data.qvel.at[1, 0].set(jnp.nan))), state)
    state, out = env.step(state, jnp.asarray(np.full((M, spec.action_dim), 0.1, np.float32)))
    assert env.step._cache_size() == 1  # one compilation for every test here
    for x, shape in ((out.obs, (M, spec.obs_dim)), (out.next_critic_obs, (M, spec.critic_obs_dim)), (out.reward, (M,))):
        assert x.shape == shape and x.dtype == jnp.float32
    assert set(out.reward_terms) == set(spec.reward_terms)
    trunc, term = np.asarray(out.truncated), np.asarray(out.terminated)
    assert trunc[0] and trunc[1] and not trunc[2:].any() and not (term & trunc).any()
    assert int(out.episode_length[0]) == limit and int(state.steps[0]) == 0 and int(state.steps[2]) == 1
    # The diverged env's outputs are zeroed, its new episode is finite; the others continue.
    assert float(out.reward[1]) == 0.0 and not np.asarray(out.next_obs[1]).any()
    assert np.isfinite(np.asarray(state.data.qvel)).all() and np.isfinite(np.asarray(out.obs)).all()
    # Auto-reset: the truncated envs start over (no last action, new observation); the others' obs is next_obs.
    np.testing.assert_array_equal(np.asarray(out.obs[2:]), np.asarray(out.next_obs[2:]))
    last_act = np.asarray(state.info["last_act"])
    assert not last_act[:2].any() and np.allclose(last_act[2:], 0.1) and float(state.episode_return[0]) == 0.0
    assert not np.allclose(np.asarray(out.obs[0]), np.asarray(out.next_obs[0]))
