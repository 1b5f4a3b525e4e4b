"""``cartpole_balance``'s step against its documented math: the task writes the array-API functions
(``observation``, ``reward_terms``, ``terminated``) out in numpy for speed; every output must stay
bit-identical to them."""

import numpy as np
import pytest

import tasks
from tasks import base
from tasks.cartpole import REWARD_TERMS, observation, reward_terms, terminated


def _reference_step(task, action) -> base.StepOut:
    """The step written with the shim functions (the task's step before it was written out)."""
    c = task.config
    a = np.clip(np.asarray(action, dtype=np.float64).reshape(task.num_envs, 1), -1.0, 1.0)
    a = np.nan_to_num(a, nan=0.0)
    unstable = task.sim.step(a)
    qpos, qvel = task.sim.qpos, task.sim.qvel
    next_obs = observation(qpos, qvel).astype(np.float32)
    terms = {k: (task.scales[k] * v).astype(np.float32) for k, v in reward_terms(qpos, qvel, a).items()}
    reward = np.sum(np.stack(list(terms.values())), axis=0).astype(np.float32)
    if unstable.any():
        next_obs[unstable] = 0.0
        reward[unstable] = 0.0
        for v in terms.values():
            v[unstable] = 0.0
    task.steps += 1
    term = terminated(qpos, c.rail_limit, c.max_angle) & ~unstable
    trunc = ((task.steps >= c.episode_length) | unstable) & ~term
    done = np.flatnonzero(term | trunc)
    obs = next_obs
    if done.size:
        task._reset_envs(done)
        obs = next_obs.copy()
        obs[done] = observation(task.sim.qpos, task.sim.qvel).astype(np.float32)[done]
    return base.StepOut(obs, obs.copy(), next_obs, next_obs.copy(), reward, term, trunc, terms)


@pytest.mark.parametrize("overrides", [
    {"episode_length": 30},
    # per-env models (domain randomisation), and a motor strong enough to diverge MuJoCo (unstable envs)
    {"episode_length": 30, "dr_motor_strength": (0.5, 1.5), "dr_pole_mass_scale": (0.5, 2.0)},
    {"motor_gear": 1e160},
])
def test_step_is_bit_identical_to_the_shim_math(overrides):
    m = 16
    fast, ref = (tasks.make("cartpole_balance", m, seed=5, overrides=overrides) for _ in range(2))
    for o1, o2 in zip(fast.reset(), ref.reset(), strict=True):
        np.testing.assert_array_equal(o1, o2)
    rng = np.random.default_rng(0)
    counts = {"terminated": 0, "truncated": 0, "unstable": 0}
    for i in range(150):
        action = rng.uniform(-1.5, 1.5, size=(m, 1)).astype(np.float32)
        if i % 7 == 0:  # non-finite actions: NaN acts as 0, inf as the limit
            action[:3, 0] = (np.nan, np.inf, -np.inf)
        got, want = fast.step(action), _reference_step(ref, action)
        for name in base.StepOut._fields[:7]:
            g, w = getattr(got, name), getattr(want, name)
            assert g.dtype == w.dtype and g.shape == w.shape, name
            np.testing.assert_array_equal(g, w, err_msg=f"step {i}: {name}")
        assert list(got.reward_terms) == list(REWARD_TERMS) == list(want.reward_terms)
        for k in REWARD_TERMS:
            assert got.reward_terms[k].dtype == np.float32
            np.testing.assert_array_equal(got.reward_terms[k], want.reward_terms[k], err_msg=f"step {i}: {k}")
        np.testing.assert_array_equal(fast.sim.state, ref.sim.state)
        counts["terminated"] += int(got.terminated.sum())
        counts["truncated"] += int(got.truncated.sum())
        counts["unstable"] += int((got.truncated & (got.next_obs == 0).all(axis=1)).sum())
    if "motor_gear" in overrides:  # every env diverges: truncated with zeroed outputs
        assert counts["unstable"] > 0 and counts["terminated"] == 0, counts
    else:
        assert counts["terminated"] > 0 and counts["truncated"] > counts["unstable"], counts
