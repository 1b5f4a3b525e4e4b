"""The MJX rough tasks (``tasks/mjx_rough.py``) against the CPU rough tasks: the same state gives the same sensors,
observations (height scan included), reward terms and end flags (Go1, through the jitted forward and transition);
the same spawn heights, curriculum moves, evaluation cells and episode metrics (Go1 and G1, eagerly); G1's heights
above the ground and its motor-strength model fields match the CPU task's.

Tolerances as ``test_mjx_parity.py``'s (float32 MJX vs float64 MuJoCo): rtol 1e-4 / atol 1e-5, except what reads
contact forces (the accelerometer: MJX's heightfield gives its own set of up to 4 contacts per foot). One jitted
compilation (forward + transition of Go1 on 4 envs, ~30 s on the 2-core VM); the rest runs eagerly.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from compile_options import FAST_COMPILE

import tasks
from tasks import go1_math, mjx_rough, terrain
from tasks.mjx_go1 import Go1MjxState, mjx
from unilab_jax.training.mjx import make_env

M = 4
OVERRIDES = {"noise_level": 0.0}  # the two engines draw different noise
ACCEL = slice(48 + 3, 48 + 6)  # accelerometer columns of Go1's critic observation


def _f32(x):
    return jnp.asarray(np.asarray(x), jnp.float32)


def _cpu_task(name, steps=15, seed=1, overrides=None):
    """A CPU rough task walked ``steps`` small random steps from reset (on its cells, feet on and off the ground)."""
    task = tasks.make(name, M, seed=seed, overrides={**OVERRIDES, **(overrides or {})})
    task.reset()
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        task.step(rng.uniform(-0.3, 0.3, (M, task.spec.action_dim)).astype(np.float32))
    return task, rng


def _data(env, qpos, qvel):
    """Batched MJX data of (qpos, qvel) after MuJoCo's own forward on the MJX model (no compilation)."""
    m, rows = env.mjx_host_model if hasattr(env, "mjx_host_model") else env.model, []
    for i in range(qpos.shape[0]):
        d = mujoco.MjData(m)
        d.qpos[:], d.qvel[:] = qpos[i], qvel[i]
        mujoco.mj_forward(m, d)
        rows.append(mjx.put_data(m, d))
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *rows)


def _mjx_episode_end(env, qpos, qvel, levels, cols, command, steps, ended, **sums):
    """``env.after_transition`` (eagerly) of one step that left the envs at ``(qpos, qvel)`` with per-env ``steps``,
    ``ended`` flags and the state's sums of the episode so far (``commanded``, ``commanded_heading``, ``walked``,
    ``asked_path``); returns (state, out)."""
    data = _data(env, qpos, np.nan_to_num(qvel)).replace(qvel=_f32(qvel))
    extra = {"level": jnp.asarray(levels, jnp.int32), "col": jnp.asarray(cols, jnp.int32),
             **{k: _f32(v) for k, v in sums.items()}}
    before = Go1MjxState(data=None, model_fields={}, pose_offset=None, info={"command": _f32(command)},
                         steps_until_next_cmd=None, steps=None, obs=None, critic_obs=None, episode_return=None,
                         episode_length=None, key=None, extra=extra)
    after = before._replace(data=data, steps=jnp.asarray(steps, jnp.int32))
    out = mjx_rough.mg.MjxStepOut(*([None] * 10))
    return env.after_transition(before, after, out, jnp.asarray(ended), jax.random.PRNGKey(0))


@pytest.fixture(scope="module")
def go1():
    return make_env("go1_joystick_rough", M, OVERRIDES, FAST_COMPILE).env


@pytest.fixture(scope="module")
def g1():
    return make_env("g1_walk_rough", M, OVERRIDES, FAST_COMPILE).env


def test_go1_same_state_gives_same_observation_reward_and_flags(go1):
    task, rng = _cpu_task("go1_joystick_rough")
    assert go1.spec == task.spec and task.rough.terrain.heights.shape == go1.sampler["heights"].shape
    qpos, qvel = task.sim.qpos.copy(), task.sim.qvel.copy()
    qpos[3, 0] = -9.5  # env 3 beyond 1 m of the map's edge: truncated
    ctrl = task._targets(task.last_act)
    dr = {k: _f32(v) for k, v in task.dr.items()}
    info = {k: jnp.asarray(v) if v.dtype == bool else _f32(v) for k, v in task.info().items()}

    def make_state(dr, info, steps, until, qpos, qvel, ctrl):
        fields = go1.model_fields(dr)
        extra = go1.init_extra(jax.random.PRNGKey(0), dr, M)
        z = jnp.zeros((M,))
        return Go1MjxState(data=go1.forward(fields, qpos, qvel, ctrl), model_fields=fields,
                           pose_offset=dr["default_pose_offset"], info=info, steps_until_next_cmd=until, steps=steps,
                           obs=jnp.zeros((M, go1.spec.obs_dim)), critic_obs=jnp.zeros((M, go1.spec.critic_obs_dim)),
                           episode_return=z, episode_length=z.astype(jnp.int32), key=jax.random.PRNGKey(1), extra=extra)

    state = jax.jit(make_state, compiler_options=FAST_COMPILE)(
        dr, info, jnp.asarray(task.steps, jnp.int32), jnp.asarray(task.steps_until_next_cmd, jnp.int32), _f32(qpos),
        _f32(qvel), _f32(ctrl))
    task.sim.set_state(np.arange(M), qpos, qvel, ctrl=ctrl)
    sensordata = task.sim.sensordata.copy()
    action = rng.uniform(-0.5, 0.5, (M, 12))
    cpu = task._after_physics(action.copy(), np.zeros(M, bool))
    _, out = jax.jit(go1.transition, compiler_options=FAST_COMPILE)(state, state.data, _f32(action))

    # Sensors: the foot contacts' "found" counts differ (each engine its own contact set), not whether one is found.
    sd = np.asarray(state.data.sensordata)
    found = [go1.sensor_index[f"{f}_floor_found"][0] for f in go1_math.FEET]
    a0 = go1.sensor_index["accelerometer"][0]
    rest = np.setdiff1d(np.arange(sd.shape[1]), [a0, a0 + 1, a0 + 2, *found])
    np.testing.assert_allclose(sd[:, rest], sensordata[:, rest], rtol=1e-4, atol=1e-5)
    np.testing.assert_array_equal(sd[:, found] > 0, sensordata[:, found] > 0)
    assert (sensordata[:, found] > 0).any() and not (sensordata[:, found] > 0).all()
    np.testing.assert_allclose(np.asarray(out.next_obs), cpu.next_obs, rtol=1e-4, atol=1e-5)
    cobs, cpu_cobs = np.asarray(out.next_critic_obs), cpu.next_critic_obs
    keep = np.ones(cobs.shape[1], bool)
    keep[ACCEL] = False
    np.testing.assert_allclose(cobs[:3, keep], cpu_cobs[:3, keep], rtol=1e-4, atol=1e-5)  # the scan: the last 187
    assert np.ptp(cpu_cobs[:3, -187:], axis=1).max() > 0.01  # uneven ground under some robot
    for k, v in cpu.reward_terms.items():
        np.testing.assert_allclose(np.asarray(out.reward_terms[k]), v, rtol=1e-4, atol=1e-6, err_msg=k)
    np.testing.assert_array_equal(np.asarray(out.terminated), cpu.terminated)
    np.testing.assert_array_equal(np.asarray(out.truncated), cpu.truncated)
    assert cpu.truncated[3] and not cpu.truncated[:3].any()


@pytest.mark.parametrize("name", ["go1", "g1"])
def test_spawn_heights_and_evaluation_cells_match_cpu(name, go1, g1):
    env = {"go1": go1, "g1": g1}[name]
    task = tasks.make(env.spec.name, 2 * M, seed=3, overrides=OVERRIDES)
    rng = np.random.default_rng(0)
    idx = np.arange(2 * M)
    qpos, _ = task.base_states(idx)  # the CPU task's: jitter and yaw, on its cells
    flat = qpos.copy()
    flat[:, :2] -= task.rough.origins(idx)[:, :2]
    task.rough.levels[:] = rng.integers(0, 10, 2 * M)  # all over the grid: stairs, obstacles, slopes
    extra = {"level": jnp.asarray(task.rough.levels, jnp.int32), "col": jnp.asarray(task.rough.cols, jnp.int32)}
    cpu = task.rough.place(flat, idx, task._stand, task._feet)
    np.testing.assert_allclose(np.asarray(env.place(_f32(flat), extra)), cpu, rtol=1e-5, atol=1e-5)

    env.frozen = True  # the evaluation layout, as the CPU task's
    try:
        frozen = env.init_extra(jax.random.PRNGKey(0), {}, 2 * M)
    finally:
        env.frozen = False
    task.rough.freeze_for_evaluation()
    np.testing.assert_array_equal(np.asarray(frozen["level"]), task.rough.levels)
    np.testing.assert_array_equal(np.asarray(frozen["col"]), task.rough.cols)
    training = env.init_extra(jax.random.PRNGKey(0), {}, 2 * M)
    assert int(training["level"].max()) <= task.config.max_init_level
    np.testing.assert_array_equal(np.asarray(training["col"]), [0, 0, 1, 2, 3, 4, 5, 6])
    saved = env.rough_config  # a resumed run's level weights (rough.resumed_level_weights): only levels 6 and 9
    env.rough_config = dataclasses.replace(saved, init_level_weights=(0,) * 6 + (0.5, 0, 0, 0.5))
    try:
        resumed = env.init_extra(jax.random.PRNGKey(1), {}, 64)
    finally:
        env.rough_config = saved
    assert set(np.asarray(resumed["level"]).tolist()) == {6, 9}


def test_terrain_curriculum_at_episode_end_matches_cpu(go1):
    """Up a level after more than half a cell, down after less than half the asked distance, kept in between, kept
    when diverged, random from the top; the metrics report the level played; the commanded paths restart."""
    task = tasks.make("go1_joystick_rough", 6, seed=0, overrides=OVERRIDES)
    task.reset()
    levels = np.array([3, 3, 3, 3, 9, 0])
    task.rough.levels[:] = levels
    origins = task.rough.origins(np.arange(6))
    qpos = task.sim.qpos.copy()
    walked = np.array([4.5, 0.2, 3.5, 0.2, 5.0, 0.1])  # metres from the origin
    qpos[:, :2] = origins[:, :2] + np.stack([walked, np.zeros(6)], 1)
    qvel = np.zeros((6, task.model.nv))
    qvel[3, 0] = np.nan  # env 3 diverged
    command = np.tile([0.5, 0.0, 0.0], (6, 1))  # asked: 0.5 m/s x 20 s = 10 m (half: 5 m); env 2: 6 m (3 m)
    command[2, 0] = 0.3
    steps = np.full(6, 100)
    dt = task.config.ctrl_dt
    path = np.stack([command[:, 0] * 99 * dt, np.zeros(6)], 1)  # 99 steps straight; the step's own at its end
    ended = np.array([True, True, True, True, True, False])

    task.rough.commanded[:] = path + np.stack([command[:, 0] * dt, np.zeros(6)], 1)
    task.rough.episode_end(np.arange(5), qpos[:5], steps[:5], np.isnan(qvel[:5]).any(axis=1))
    state, out = _mjx_episode_end(go1, qpos, qvel, levels, task.rough.cols, command, steps, ended, commanded=path,
                                  commanded_heading=np.zeros(6), walked=np.zeros(6), asked_path=np.zeros(6))
    new = np.asarray(state.extra["level"])
    np.testing.assert_array_equal(new[:4], task.rough.levels[:4])
    np.testing.assert_array_equal(new[:4], [4, 2, 3, 3])
    assert 0 <= new[4] < 10 and new[5] == 0  # promoted past the top: a random level; not ended: kept
    np.testing.assert_array_equal(np.asarray(out.extras["terrain_level"]), levels)
    np.testing.assert_array_equal(np.asarray(out.extras["terrain_level_3"]), levels == 3)
    np.testing.assert_allclose(np.asarray(state.extra["commanded"])[:, 0], [0, 0, 0, 0, 0, 100 * 0.5 * dt], rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(state.extra["commanded_heading"]), np.zeros(6))


def test_path_curriculum_at_episode_end_matches_cpu():
    """``curriculum_distance="path"`` (Go2's and G1's): up after more than half a cell made along the command, down
    after less than half of the commanded path, kept in between and when diverged; the sums restart at episode end.
    The MJX side adds the last step's velocity itself; the CPU side gets it through ``record_step``."""
    over = {**OVERRIDES, "curriculum_distance": "path"}
    env = make_env("go1_joystick_rough", M, over, FAST_COMPILE).env
    task = tasks.make("go1_joystick_rough", 6, seed=0, overrides=over)
    task.reset()
    levels = np.array([3, 3, 3, 3, 9, 0])
    task.rough.levels[:] = levels
    qpos = task.sim.qpos.copy()
    qpos[:, 2] += 0.3  # feet off the ground: MuJoCo's heightfield contacts would overrun MJX's contact budget
    yaw = terrain.yaw_from_quat(qpos[:, 3:7])  # the reset's headings
    qvel = np.zeros((6, task.model.nv))
    qvel[:, :2] = 0.5 * np.stack([np.cos(yaw), np.sin(yaw)], axis=1)  # 0.5 m/s along each heading
    qvel[3, 0] = np.nan  # env 3 diverged
    command = np.tile([0.5, 0.0, 0.0], (6, 1))  # asked: 0.5 m/s x 20 s = 10 m (half: 5 m); env 2: 6 m (3 m)
    command[2, 0] = 0.3
    dt, steps = task.config.ctrl_dt, np.full(6, 100)
    walked0 = np.array([4.5, 0.2, 3.5, 0.2, 5.0, 0.1])  # made along the command in the first 99 steps
    asked0 = command[:, 0] * 99 * dt
    ended = np.array([True, True, True, True, True, False])

    task.rough.walked[:], task.rough.asked_path[:] = walked0, asked0
    task.rough.record_step(command, np.zeros(6), np.nan_to_num(qvel[:, :2]), yaw)
    task.rough.episode_end(np.arange(5), qpos[:5], steps[:5], np.isnan(qvel[:5]).any(axis=1))
    state, out = _mjx_episode_end(env, qpos, qvel, levels, task.rough.cols, command, steps, ended,
                                  commanded=np.zeros((6, 2)), commanded_heading=np.zeros(6), walked=walked0,
                                  asked_path=asked0)
    new = np.asarray(state.extra["level"])
    np.testing.assert_array_equal(new[:4], task.rough.levels[:4])
    np.testing.assert_array_equal(new[:4], [4, 2, 3, 3])
    assert 0 <= new[4] < 10 and new[5] == 0
    np.testing.assert_allclose(np.asarray(state.extra["walked"]), [0, 0, 0, 0, 0, 0.1 + 0.5 * dt], rtol=1e-5)
    np.testing.assert_allclose(np.asarray(state.extra["asked_path"]), [0, 0, 0, 0, 0, 0.5 * 100 * dt], rtol=1e-5)
    np.testing.assert_array_equal(task.rough.walked[:5], 0.0)


def test_g1_heights_above_ground_and_motor_strength_match_cpu(g1):
    task, _ = _cpu_task("g1_walk_rough", steps=10)
    assert g1.spec == task.spec
    qpos, qvel = task.sim.qpos.copy(), task.sim.qvel.copy()
    task.sim.set_state(np.arange(M), qpos, qvel, ctrl=task._ctrl(task.last_act))  # sensors at qpos (forward)
    cpu = task._sensors()
    info = {"command": _f32(task.command), "last_act": _f32(task.last_act)}
    s = g1.sensors(_data(g1, qpos, qvel), info, jnp.asarray(task.steps, jnp.int32))
    for k in ("base_z", "feet_h"):
        np.testing.assert_allclose(np.asarray(s[k]), cpu[k], rtol=1e-4, atol=1e-5, err_msg=k)
    assert np.abs(cpu["base_z"] - qpos[:, 2]).max() > 0.01  # some robot stands above raised ground
    # Motor strength: the per-env servo gains, bias and damping of the CPU task's models.
    assert "motor_strength" in task.dr and "action_delay" in task.dr
    fields = g1.model_fields({k: _f32(v) for k, v in task.dr.items()})
    for k in ("actuator_gainprm", "actuator_biasprm", "dof_damping", "body_mass"):
        cpu_field = np.stack([getattr(mi, k) for mi in task.sim.models])
        np.testing.assert_allclose(np.asarray(fields[k]), cpu_field, rtol=1e-6, atol=1e-6, err_msg=k)
    queue = g1.init_extra(jax.random.PRNGKey(0), {k: _f32(v) for k, v in task.dr.items()}, M)
    np.testing.assert_array_equal(np.asarray(queue["delay"]), task.delay.delays)


def test_a_base_through_the_ground_or_thrown_truncates_on_both_engines(g1):
    """``base_height_band``: a G1 whose pelvis is 1 m under the ground under it (fallen through the heightfield) or
    4 m above it (thrown) is at its limit on the CPU task and on MJX; one standing or lying on the ground is not."""
    task, _ = _cpu_task("g1_walk_rough", steps=3)
    assert task.rough.config.base_height_band == (-0.5, 3.0)
    qpos, qvel = task.sim.qpos.copy(), task.sim.qvel.copy()
    ground = task.base_ground()
    qpos[0, 2] = ground[0] - 1.0  # through the ground
    qpos[1, 2] = ground[1] + 4.0  # thrown
    qpos[2, 2] = ground[2] + 0.1  # lying on it
    task.sim.set_state(np.arange(M), qpos, qvel)
    np.testing.assert_array_equal(task.at_limit(), [True, True, False, False])
    np.testing.assert_array_equal(np.asarray(g1.at_limit(_data(g1, qpos, qvel))), [True, True, False, False])
    # a step from there ends both episodes (the sunk one also under G1's min_base_height, a termination, which wins;
    # the thrown one truncated): their robots restart on their cells
    out = task.step(np.zeros((M, task.spec.action_dim), np.float32))
    assert out.terminated[0] and out.truncated[1] and not out.terminated[1]
    assert (task.sim.qpos[:2, 2] - task.base_ground()[:2] > 0.5).all()
