"""``physics_threads``: a task's envs stepped by a pool of MuJoCo threads (``mujoco.rollout`` with
``nthread``) give exactly the single-threaded trajectories."""

from __future__ import annotations

import numpy as np
import pytest

import tasks
from tasks.physics import BatchedSim


@pytest.mark.parametrize("task", ["go1_joystick_flat", "go2_joystick_flat"])
def test_threaded_rollout_matches_single_thread(task):
    runs = []
    for threads in (1, 3):
        t = tasks.make(task, 8, seed=3, overrides={"physics_threads": threads})
        rng = np.random.default_rng(0)
        obs, _ = t.reset()
        outs = []
        for _ in range(15):
            out = t.step(rng.uniform(-1, 1, (8, t.spec.action_dim)).astype(np.float32))
            outs.append((out.obs, out.reward, out.terminated))
        runs.append((outs, t.sim.qpos.copy()))
        t.close()
    (a, qa), (b, qb) = runs
    np.testing.assert_array_equal(qa, qb)
    for (oa, ra, ta), (ob, rb, tb) in zip(a, b):
        np.testing.assert_array_equal(oa, ob)
        np.testing.assert_array_equal(ra, rb)
        np.testing.assert_array_equal(ta, tb)


def test_threads_need_the_rollout_engine():
    t = tasks.make("go1_joystick_flat", 1, seed=0)
    with pytest.raises(ValueError, match="nthread"):
        BatchedSim(t.model, 2, 2, engine="step", nthread=2)
    with pytest.raises(ValueError, match="nthread"):
        BatchedSim(t.model, 2, 2, nthread=0)
    t.close()
