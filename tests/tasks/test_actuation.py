"""Action latency and motor strength (``tasks/actuation.py``, the tasks' ``dr_action_delay`` / ``dr_motor_strength``):
the queue by hand, a one-step delay on the real simulation, the force scale on the randomised models."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import tasks
from tasks import actuation

CLEAN = {"noise_level": 0.0, "domain_randomization": False}


def test_delay_actions_by_hand():
    queue = np.array([[[1.0], [2.0]], [[10.0], [20.0]], [[5.0], [6.0]]])  # newest first
    action = np.array([[0.5], [0.7], [0.9]])
    applied, nxt = actuation.delay_actions(queue, action, np.array([0, 1, 2]))
    np.testing.assert_array_equal(applied, [[0.5], [10.0], [6.0]])
    np.testing.assert_array_equal(nxt, [[[0.5], [1.0]], [[0.7], [10.0]], [[0.9], [5.0]]])
    with pytest.raises(ValueError, match="dr_action_delay"):
        actuation.sample_delays(np.random.default_rng(0), (1, 0), 4)
    assert actuation.sample_delays(np.random.default_rng(0), (0, 0), 4) is None


@pytest.mark.parametrize("name", ["go1_joystick_flat", "go2_joystick_flat"])
def test_one_step_latency_delays_the_action_by_exactly_one_step(name):
    task = tasks.make(name, 2, seed=0, overrides={**CLEAN, "dr_action_delay": (0, 1)})
    task.reset()
    task.delay.delays[:] = [0, 1]  # env 0 acts at once, env 1 one control step late
    task.sim.set_state(np.arange(2), np.tile(task.sim.qpos[:1], (2, 1)), np.tile(task.sim.qvel[:1], (2, 1)))
    acts = np.random.default_rng(1).uniform(-1, 1, (4, task.spec.action_dim)).astype(np.float32)
    # env 0 gets (0, a1, a2, a3), env 1 (a1, a2, a3, a4): with the delay both motors see the same targets
    for k in range(4):
        prev = np.zeros_like(acts[0]) if k == 0 else acts[k - 1]
        out = task.step(np.stack([prev, acts[k]]))
        assert not (out.terminated | out.truncated).any()
        np.testing.assert_array_equal(task.sim.qpos[0], task.sim.qpos[1])
    # the observation shows the policy's own last action, not the delayed one
    np.testing.assert_allclose(task.last_act[1], acts[3], rtol=1e-6)
    task.close()


def test_rough_tasks_draw_latency_and_motor_strength_by_default():
    task = tasks.make("go1_joystick_rough", 16, seed=0, overrides={"terrain_levels": 2, "max_init_level": 1})
    delays = task.dr["action_delay"][:, 0]
    assert set(delays) == {0.0, 1.0}
    np.testing.assert_array_equal(task.delay.delays, delays)
    layout = dict(task.extrinsics_layout)
    assert layout["action_delay"] == 1 and layout["motor_strength"] == 12
    strength = task.dr["motor_strength"]
    assert ((strength >= 0.9) & (strength <= 1.1)).all() and np.ptp(strength) > 0.1
    # each env's servo force at the same state and targets is its strength times the nominal force
    m0 = task.model
    for i in (0, 5):
        forces = []
        for model in (m0, task.sim.models[i]):
            d = mujoco.MjData(model)
            d.qpos[:] = task.init_qpos
            d.ctrl[:] = task.default_pose + 0.01
            mujoco.mj_forward(model, d)
            forces.append(d.actuator_force.copy())
        np.testing.assert_allclose(forces[1], forces[0] * strength[i], rtol=1e-9)
    task.close()


def test_walking_motor_strength_scales_gain_and_damping():
    over = {"dr_motor_strength": (0.5, 1.5), "dr_floor_friction": (0.6, 0.6), "dr_mass_scale": (1.0, 1.0),
            "dr_torso_com": 0.0}
    task = tasks.make("g1_walk_flat", 3, seed=0, overrides=over)
    strength = task.dr["motor_strength"]
    assert strength.shape == (3, task.model.nu) and "action_delay" not in task.dr
    for i, model in enumerate(task.sim.models):
        np.testing.assert_allclose(model.actuator_gainprm[:, 0], task.model.actuator_gainprm[:, 0] * strength[i])
        np.testing.assert_allclose(model.actuator_biasprm[:, 1], task.model.actuator_biasprm[:, 1] * strength[i])
        vadr = task.model.jnt_dofadr[task.model.actuator_trnid[:, 0]]
        np.testing.assert_allclose(model.dof_damping[vadr], task.model.dof_damping[vadr] * strength[i])
    task.close()
    flat = tasks.make("g1_walk_flat", 3, seed=0)
    assert "motor_strength" not in flat.dr  # off by default on flat ground: the flat task's draws unchanged
    flat.close()
