"""The MJX variants of go2_joystick_flat and g1_walk_flat (``tasks/mjx_walking.py``) are the CPU tasks' MDP:
same observation, critic observation, reward terms and end flags for the same state, domain randomisation
with the CPU task's model fields, physics that tracks MuJoCo's, and the step contract under ``jax.jit``.

Tolerances (float32 MJX vs float64 MuJoCo), as ``test_mjx_parity.py``'s:

* sensors, observations and every reward term from the same state (both engines run forward on it, then
  the post-physics step: ``WalkingTask._after_physics`` on the CPU, ``WalkingMjx.transition`` on MJX):
  rtol 1e-4 / atol 1e-5 (reward terms atol 1e-7); contacts, stance and end flags exactly. The state is
  chosen to exercise the gait clock at its stance/swing boundaries (where float32 time would disagree
  with the CPU's float64 clock), a push (Go2), and a terminated env (tilted 70 degrees).
* one control step (physics included) from the same state, default friction loss: qpos within 1e-4
  (measured 3e-7 Go2, 1.6e-6 G1), critic observation within 2e-3 (measured 4e-5 / 3e-4, joint
  velocities), reward within 1e-5 (measured ~1e-7). Then the step contract under jit: truncation at the time
  limit and on divergence (zeroed outputs), auto-reset, one compilation.
* domain randomisation: ``model_fields(task.dr)`` equals the CPU task's per-env models' fields (rtol 1e-6);
  the jax draws have the CPU draws' ranges and means (4000 draws each).

Runtime ~80 s on the 2-core dev VM, nearly all XLA compilation of forward, transition and step per task.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compile_options import FAST_COMPILE

import tasks
from tasks.mjx_walking import WalkingMjxState
from unilab_jax.training.mjx import make_env

M = 4
OPTS = FAST_COMPILE  # less XLA compile time; numerics unchanged
OVERRIDES = {"noise_level": 0.0}  # the two engines draw different noise
TASKS = ("go2_joystick_flat", "g1_walk_flat")
QPOS_TOL = {"go2_joystick_flat": 1e-4, "g1_walk_flat": 1e-4}
OBS_TOL = 2e-3


@pytest.fixture(scope="module", params=TASKS)
def case(request):
    """(task name, jitted env, jitted ``make_state``, jitted transition): one compilation of each per task."""
    env = make_env(request.param, M, OVERRIDES, OPTS)
    e = env.env

    def make_state(dr, command, last_act, steps, qpos, qvel, ctrl):
        """An MJX state at the CPU task's (qpos, qvel, ctrl) after ``mjx.forward``, with its domain
        randomisation draw and episode state (``obs`` left at 0)."""
        fields = e.model_fields(dr)
        z = jnp.zeros((M,))
        return WalkingMjxState(data=e.forward(fields, qpos, qvel, ctrl), model_fields=fields,
                        info={"command": command, "last_act": last_act}, steps=steps,
                        obs=jnp.zeros((M, e.spec.obs_dim)), critic_obs=jnp.zeros((M, e.spec.critic_obs_dim)),
                        episode_return=z, episode_length=z.astype(jnp.int32), key=jax.random.PRNGKey(0))

    return (request.param, env, jax.jit(make_state, compiler_options=OPTS),
            jax.jit(e.transition, compiler_options=OPTS))


def _cpu_task(name, steps=12, seed=1):
    """A CPU task walked ``steps`` small random steps from reset (feet on and off the floor)."""
    task = tasks.make(name, M, seed=seed, overrides=OVERRIDES)
    task.reset()
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        task.step(rng.uniform(-0.3, 0.3, (M, task.spec.action_dim)).astype(np.float32))
    return task, rng


def _edit(fn, *args):
    """``fn(*args)`` under jit: uncommitted outputs like ``reset``'s, so jitted functions compile once."""
    return jax.jit(fn)(*args)


def _f32(x):
    return jnp.asarray(np.asarray(x), jnp.float32)


def _mjx_state(make_state, task, qpos, qvel, ctrl):
    """The MJX state of the CPU task's envs at (qpos, qvel, ctrl)."""
    dr = {k: _f32(v) for k, v in task.dr.items()}
    return make_state(dr, _f32(task.command), _f32(task.last_act), jnp.asarray(task.steps, jnp.int32), _f32(qpos),
                      _f32(qvel), _f32(ctrl))


def _period(task):
    return round(1.0 / (task.config.gait_frequency * task.dt))  # control steps per gait cycle


def test_same_state_gives_same_observation_reward_and_flags(case):
    name, env, make_state, transition = case
    e = env.env
    task, rng = _cpu_task(name)
    assert e.spec == task.spec
    # Episode steps (before this step's increment): half and full gait cycles (stance/swing boundaries), a
    # push step when the task pushes, and an env tilted 70 degrees (terminated).
    p = _period(task)
    push = task._push_every
    task.steps[:] = [p // 2 - 1, p - 1, push - 1 if push else 2 * p - 1, 7]
    qpos, qvel = task.sim.qpos.copy(), task.sim.qvel.copy()
    qpos[3, 2] += 0.5
    qpos[3, 3:7] = [math.cos(math.radians(35)), math.sin(math.radians(35)), 0.0, 0.0]
    ctrl = task._ctrl(task.last_act)
    state = _mjx_state(make_state, task, qpos, qvel, ctrl)
    data = state.data
    task.sim.set_state(np.arange(M), qpos, qvel, ctrl=ctrl)
    sensordata, steps_before = task.sim.sensordata.copy(), task.steps.copy()
    action = rng.uniform(-0.5, 0.5, (M, task.spec.action_dim))
    cpu = task._after_physics(action.copy(), np.zeros(M, bool))
    pushed_cpu = np.abs(task.sim.qvel[:3, :3] - qvel[:3, :3]).max(axis=1) > 0  # env 3 was reset
    new_state, out = transition(state, data, _f32(action))

    # Sensors (CPU layout; G1's per-body foot contacts are summed from per-sphere sensors).
    sd = np.asarray(e.cpu_sensordata(data.sensordata))
    np.testing.assert_allclose(sd, sensordata, rtol=1e-4, atol=1e-5)
    contact = np.stack([sensordata[:, task._sensor[f"{f}_contact"][0]] for f in task.FEET], axis=1) > 0
    assert contact.any() and not contact.all()  # a non-trivial state
    np.testing.assert_array_equal(np.stack([sd[:, task._sensor[f"{f}_contact"][0]] for f in task.FEET], 1) > 0,
                                  contact)
    # Observations, reward terms, end flags.
    np.testing.assert_allclose(np.asarray(out.next_obs), cpu.next_obs, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(out.next_critic_obs), cpu.next_critic_obs, rtol=1e-4, atol=1e-5)
    assert set(out.reward_terms) == set(cpu.reward_terms) == set(task.spec.reward_terms)
    for k, v in cpu.reward_terms.items():
        np.testing.assert_allclose(np.asarray(out.reward_terms[k]), v, rtol=1e-4, atol=1e-7, err_msg=k)
    np.testing.assert_allclose(np.asarray(out.reward), cpu.reward, rtol=1e-4, atol=1e-7)
    np.testing.assert_array_equal(cpu.terminated, [False, False, False, True])
    np.testing.assert_array_equal(np.asarray(out.terminated), cpu.terminated)
    np.testing.assert_array_equal(np.asarray(out.truncated), cpu.truncated)
    # Bookkeeping: step counter, last action, pushes (same envs; the draws differ).
    np.testing.assert_array_equal(np.asarray(new_state.steps), steps_before + 1)
    np.testing.assert_allclose(np.asarray(new_state.info["last_act"]), action, rtol=1e-6)
    pushed_mjx = np.abs(np.asarray(new_state.data.qvel[:3, :3]) - qvel[:3, :3]).max(axis=1) > 1e-6
    np.testing.assert_array_equal(pushed_mjx, pushed_cpu)
    assert pushed_cpu.any() == bool(push)


def test_domain_randomisation_matches_cpu_models(case):
    name, env, _, _ = case
    e = env.env
    task, _ = _cpu_task(name, steps=0)
    fields = e.model_fields({k: np.asarray(v, np.float32) for k, v in task.dr.items()})
    assert set(fields) == set(e.dr_spec.fields)
    for k, v in fields.items():
        cpu = np.stack([getattr(mi, k) for mi in task.sim.models])
        np.testing.assert_allclose(np.asarray(v), cpu, rtol=1e-6, atol=1e-7, err_msg=k)
    # The jax draws have the CPU task's distributions (compared on 4000 draws of each).
    n = 4000
    task.num_envs = n
    ref = task.sample_dr()
    drawn = e.sample_dr(jax.random.PRNGKey(1), n)
    assert {k: v.shape for k, v in drawn.items()} == {k: v.shape for k, v in ref.items()}
    for k, v in drawn.items():
        v, r = np.asarray(v), ref[k]
        width = np.ptp(r)
        assert width > 0, k
        assert abs(v.min() - r.min()) < 0.01 * width and abs(v.max() - r.max()) < 0.01 * width, k
        assert abs(v.mean() - r.mean()) < 0.02 * width, k


def test_step_tracks_mujoco_and_keeps_contract(case):
    """One jitted step from the CPU task's state tracks MuJoCo; the end-of-episode contract: a terminated
    env and a diverged one (NaN velocity) end and auto-reset, the others continue."""
    name, env, make_state, _ = case
    spec = env.env.spec
    task, rng = _cpu_task(name, seed=2)
    qpos, qvel, ctrl = task.sim.qpos.copy(), task.sim.qvel.copy(), task._ctrl(task.last_act)
    task.sim.set_state(np.arange(M), qpos, qvel, ctrl=ctrl)
    state = _mjx_state(make_state, task, qpos, qvel, ctrl)
    action = rng.uniform(-0.5, 0.5, (M, spec.action_dim)).astype(np.float32)
    cpu = task.step(action)
    new, out = env.step(state, jnp.asarray(action))
    assert env.step._cache_size() == 1
    assert not (cpu.terminated | cpu.truncated).any() and not np.asarray(out.terminated | out.truncated).any()
    err = np.abs(np.asarray(new.data.qpos) - task.sim.qpos).max()
    obs_err = np.abs(np.asarray(out.next_critic_obs) - cpu.next_critic_obs).max()
    rew_err = np.abs(np.asarray(out.reward) - cpu.reward).max()
    print(f"{name}: one-step qpos error {err:.2e}, critic obs {obs_err:.2e}, reward {rew_err:.2e}")
    assert err < QPOS_TOL[name], err
    np.testing.assert_allclose(np.asarray(out.next_critic_obs), cpu.next_critic_obs, atol=OBS_TOL)
    np.testing.assert_allclose(np.asarray(out.reward), cpu.reward, atol=1e-5)
    # Contract: env 0 at its last step, env 1 diverged; shapes and dtypes of the TaskSpec.
    limit = spec.episode_length
    state = _edit(lambda st: st._replace(steps=st.steps.at[0].set(limit - 1),
                                         data=st.data.replace(qvel=st.data.qvel.at[1, 0].set(jnp.nan))), new)
    state, out = env.step(state, jnp.asarray(action))
    assert env.step._cache_size() == 1
    for x, shape in ((out.obs, (M, spec.obs_dim)), (out.next_critic_obs, (M, spec.critic_obs_dim)),
                     (out.reward, (M,))):
        assert x.shape == shape and x.dtype == jnp.float32
    trunc, term = np.asarray(out.truncated), np.asarray(out.terminated)
    assert trunc[0] and trunc[1] and not trunc[2:].any() and not term.any()
    assert float(out.reward[1]) == 0.0 and not np.asarray(out.next_obs[1]).any()
    assert np.isfinite(np.asarray(state.data.qvel)).all() and np.isfinite(np.asarray(out.obs)).all()
    np.testing.assert_array_equal(np.asarray(state.steps), [0, 0, *(np.asarray(new.steps[2:]) + 1)])
    np.testing.assert_array_equal(np.asarray(out.obs[2:]), np.asarray(out.next_obs[2:]))
    assert not np.asarray(state.info["last_act"][:2]).any()
