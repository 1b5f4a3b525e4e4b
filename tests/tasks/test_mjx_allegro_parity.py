"""The MJX variant of allegro_rotate is the CPU task's MDP (boxes only, see tasks/mjx_allegro.py): the same
observation and reward from the same state, a control step from the same state and action that tracks
MuJoCo's, and the end-of-episode contract under ``jax.jit``. Kept cheap: 2 envs, the MJX data built from
MuJoCo's (``mjx.put_data``) so only ``transition`` and ``step`` compile.

Tolerances (float32 MJX vs float64 MuJoCo), measured: from the same state, observations and reward terms
agree to ~1e-6 relative (checked at rtol 1e-4 / atol 1e-5); after one control step from the same state
and action (10 substeps, object on the palm): qpos within 1.3e-7, observations 4e-6 (joint velocities),
reward 2e-8 (checked at 1e-5, 1e-4, 1e-5). The test costs ~27 s of CPU (two compilations).
"""

from __future__ import annotations

import contextlib
import io

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from compile_options import FAST_COMPILE

import tasks
from tasks import mjx_allegro

with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx

M = 2
# The privileged actor (object state in the extrinsics and the actor's observation): its columns are compared too.
OVERRIDES = {"noise_level": 0.0, "shapes": ("box",), "episode_length": 100, "object_state_extrinsics": True,
             "actor_extrinsics": True}
# The MJX env's resets press (``reset_press``; the CPU task's state is mirrored, so the step is the same): with
# the CPU task pressing too, the random walk before the step pressed the fingers into the object and the
# float32 step drifted 1.5e-4 from MuJoCo's in the object's pose.
PRESS = 0.25
OPTS = FAST_COMPILE  # less XLA compile time; numerics unchanged


def _cpu_task(seed=1, steps=5):
    """A CPU task walked a few random steps from reset (fingers away from the canonical pose, object moved)."""
    task = tasks.make("allegro_rotate", M, seed=seed, overrides=OVERRIDES)
    task.reset()
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        task.step(rng.uniform(-1, 1, (M, 16)).astype(np.float32))
    return task, rng


def _mirror(env, task):
    """An MJX state with the CPU task's current physics state (``put_data`` of each env's MjData after
    ``mj_forward``), per-env object fields, object parameters and bookkeeping."""
    datas = []
    for i, m in enumerate(task.sim.models):
        d = mujoco.MjData(m)
        d.qpos[:], d.qvel[:], d.ctrl[:] = task.sim.qpos[i], task.sim.qvel[i], task.info["target"][i]
        mujoco.mj_forward(m, d)
        datas.append(mjx.put_data(m, d, impl="jax"))
    data = jax.tree_util.tree_map(lambda *x: jnp.stack(x).astype(x[0].dtype), *datas)
    fields = {k: jnp.asarray(np.stack([getattr(m, k) for m in task.sim.models]), jnp.float32)
              for k in mjx_allegro.GEOM_FIELDS + mjx_allegro.BODY_FIELDS}
    info = {k: jnp.asarray(v, jnp.float32) for k, v in task.info.items()}
    return mjx_allegro.AllegroMjxState(data=data, model_fields=fields, params=jnp.asarray(task.params, jnp.float32),
                                info=info, steps=jnp.asarray(task.steps, jnp.int32), obs=jnp.zeros((M, 48)),
                                critic_obs=jnp.zeros((M, 88)), episode_return=jnp.zeros(M),
                                episode_length=jnp.zeros(M, jnp.int32), key=jax.random.PRNGKey(0))


def test_mjx_matches_cpu_task():
    env = mjx_allegro.make(tasks.allegro_rotate.AllegroRotateConfig(**OVERRIDES, reset_press=PRESS), M)
    task, rng = _cpu_task()
    assert env.spec == task.spec
    assert task.unstable_count == 0
    # Same state -> same observation and reward (both run the task math on their own forward pass).
    state = _mirror(env, task)
    _, out = jax.jit(env.transition, compiler_options=OPTS)(state, state.data)
    qpos, qvel = task.sim.qpos.copy(), task.sim.qvel.copy()
    task.sim.set_state(np.arange(M), qpos, qvel, ctrl=task.info["target"])
    cpu = task._after_physics(np.zeros(M, bool))
    np.testing.assert_allclose(np.asarray(out.next_obs), cpu.next_obs, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(out.next_critic_obs), cpu.next_critic_obs, rtol=1e-4, atol=1e-5)
    assert set(out.reward_terms) == set(cpu.reward_terms)
    for k, v in cpu.reward_terms.items():
        np.testing.assert_allclose(np.asarray(out.reward_terms[k]), v, rtol=1e-4, atol=1e-6, err_msg=k)
    np.testing.assert_allclose(np.asarray(out.reward), cpu.reward, rtol=1e-4, atol=1e-6)
    assert (cpu.reward_terms["pose_diff"] < 0).all() and (cpu.reward_terms["torque"] < 0).all()

    # Same state and action -> the same control step; env 1 at its time limit is truncated and reset.
    state = _mirror(env, task)._replace(steps=jnp.asarray([0, 99], jnp.int32))
    task.steps[:] = [0, 99]
    action = rng.uniform(-1, 1, (M, 16)).astype(np.float32)
    step = jax.jit(env.step, compiler_options=OPTS)
    new, out = step(state, jnp.asarray(action))
    cpu = task.step(action)
    np.testing.assert_array_equal(np.asarray(out.truncated), cpu.truncated)
    assert cpu.truncated.tolist() == [False, True] and not cpu.terminated.any()
    np.testing.assert_allclose(np.asarray(new.data.qpos[0]), task.sim.qpos[0], atol=1e-5)
    np.testing.assert_allclose(np.asarray(out.next_obs), cpu.next_obs, atol=1e-4)
    np.testing.assert_allclose(np.asarray(out.reward), cpu.reward, atol=1e-5)
    # Env 1 starts over: its step counter, targets and object are the new episode's.
    assert int(new.steps[0]) == 1 and int(new.steps[1]) == 0
    np.testing.assert_array_equal(np.asarray(out.obs[0]), np.asarray(out.next_obs[0]))
    assert not np.allclose(np.asarray(out.obs[1]), np.asarray(out.next_obs[1]))
    assert abs(float(new.params[1, 0]) - float(state.params[1, 0])) > 0  # a new object mass was drawn
    press = tasks.allegro_rotate.press_offset(PRESS)
    np.testing.assert_allclose(np.asarray(new.info["target"][1] - new.data.qpos[1, :16]), press, atol=1e-6)


def test_mjx_resets_from_the_cpu_tasks_grasp_cache():
    """With ``grasp_cache`` both engines start episodes from the same file's grasps (the boxes here): each MJX
    env's joints, object pose, targets and object parameters are one cached grasp's, as the CPU task's are."""
    overrides = {**OVERRIDES, "grasp_cache": "builtin", "reset_press": 0.0}
    env = mjx_allegro.make(tasks.allegro_rotate.AllegroRotateConfig(**overrides), M)
    cpu = tasks.make("allegro_rotate", M, seed=0, overrides=overrides)
    for k in ("qpos", "target", "mass", "start", "count"):
        np.testing.assert_array_equal(np.asarray(env.grasps[k]), cpu.grasps[k], err_msg=k)
    state = jax.jit(env.reset, compiler_options=OPTS)(jax.random.PRNGKey(3))
    qpos = np.asarray(state.data.qpos)
    rows = [int(np.argmin(np.abs(cpu.grasps["qpos"] - q).max(axis=1))) for q in qpos]
    np.testing.assert_allclose(qpos, cpu.grasps["qpos"][rows], atol=1e-7)
    np.testing.assert_allclose(np.asarray(state.info["target"]), cpu.grasps["target"][rows], atol=1e-7)
    np.testing.assert_allclose(np.asarray(state.params[:, 0]), cpu.grasps["mass"][rows], rtol=1e-6)
    cpu.close()
