"""History variants (``<task>_hist``) and the extrinsics the teacher/student methods read."""

from __future__ import annotations

import numpy as np
import pytest

import tasks
from tasks.history import HistorySpec, split_obs

DR = {"dr_motor_strength": (0.5, 1.5), "dr_pole_mass_scale": (0.5, 3.0)}


def test_history_frames_follow_the_base_task():
    m, h = 5, 4
    base = tasks.make("cartpole_balance", m, seed=3, overrides=DR)
    hist = tasks.make("cartpole_balance_hist", m, seed=3, overrides={**DR, "history_len": h, "history_exclude": (3, 4)})
    s = hist.spec
    assert isinstance(s, HistorySpec) and (s.frame_dim, s.history_len, s.extrinsics_in_obs) == (3, h, True)
    assert (s.obs_dim, s.critic_obs_dim, s.privileged_dim) == (3 * h + 2, 5 + 2, 2)
    b_obs, _ = base.reset()
    obs, cobs = hist.reset()
    frames, ext = split_obs(s, obs)
    np.testing.assert_array_equal(frames, np.repeat(b_obs[:, None, :3], h, axis=1))  # first frame repeated
    np.testing.assert_array_equal(ext, base.extrinsics)
    np.testing.assert_array_equal(cobs[:, 5:], base.extrinsics)
    rng = np.random.default_rng(0)
    ended_any = False
    for _ in range(60):
        a = rng.uniform(-1, 1, size=(m, 1)).astype(np.float32)
        bo, ho = base.step(a), hist.step(a)
        np.testing.assert_array_equal(ho.reward, bo.reward)
        nf, _ = split_obs(s, ho.next_obs)
        of, _ = split_obs(s, ho.obs)
        np.testing.assert_array_equal(nf[:, -1], bo.next_obs[:, :3])
        np.testing.assert_array_equal(nf[:, :-1], frames[:, 1:])  # shifted by one step
        ended = bo.terminated | bo.truncated
        np.testing.assert_array_equal((ho.obs == ho.next_obs).all(axis=1), ~ended)
        np.testing.assert_array_equal(of[ended], np.repeat(bo.obs[ended][:, None, :3], h, axis=1))
        np.testing.assert_array_equal(of[~ended], nf[~ended])
        np.testing.assert_array_equal(ho.next_critic_obs[:, :5], bo.next_critic_obs)
        ended_any |= ended.any()
        frames = of
    assert ended_any


def test_variant_options_and_forwarding():
    t = tasks.make("go1_joystick_flat_hist", 2, seed=0, overrides={"history_len": 3, "history_extrinsics": False,
                                                                    "history_exclude": (0, 1, 2)})
    assert (t.spec.obs_dim, t.spec.critic_obs_dim, t.spec.frame_dim) == (3 * 45, 123, 45)
    obs, _ = t.reset()
    assert obs.shape == (2, 135)
    assert t.command.shape == (2, 3) and t.base_velocity().shape == (2, 3)  # forwarded (walking metric)
    t.close()
    with pytest.raises(ValueError, match="outside"):
        tasks.make("cartpole_balance_hist", 1, overrides={"history_exclude": (9,)})


def test_cartpole_domain_randomisation_is_off_by_default_and_exposed():
    off = tasks.make("cartpole_balance", 3, seed=1)
    assert off.sim.models is None and off.spec.privileged_dim == 2
    np.testing.assert_array_equal(off.extrinsics, np.ones((3, 2), np.float32))
    on = tasks.make("cartpole_balance", 3, seed=1, overrides=DR)
    gear = off.model.actuator_gear[0, 0]
    pole = off.model.body("pole").id
    np.testing.assert_allclose([m.actuator_gear[0, 0] for m in on.sim.models], gear * on.dr["motor_strength"][:, 0])
    np.testing.assert_allclose([m.body_mass[pole] for m in on.sim.models],
                               off.model.body_mass[pole] * on.dr["pole_mass_scale"][:, 0])
    assert [k for k, _ in on.extrinsics_layout] == ["motor_strength", "pole_mass_scale"]
    assert np.ptp(on.extrinsics, axis=0).min() > 0


def test_go1_motor_strength():
    off = tasks.make("go1_joystick_flat", 3, seed=2)
    on = tasks.make("go1_joystick_flat", 3, seed=2, overrides={"dr_motor_strength": (0.8, 1.2)})
    for k in off.dr:  # enabling it leaves every other draw unchanged
        if k != "motor_strength":
            np.testing.assert_array_equal(off.dr[k], on.dr[k])
    np.testing.assert_array_equal(off.dr["motor_strength"], 1.0)
    assert all((m.actuator_gainprm[:, 0] == 35.0).all() for m in off.sim.models)
    s = on.dr["motor_strength"]
    assert ((s >= 0.8) & (s <= 1.2)).all() and np.ptp(s) > 0
    for i, m in enumerate(on.sim.models):
        np.testing.assert_allclose(m.actuator_gainprm[:, 0], 35.0 * s[i])
        np.testing.assert_allclose(m.actuator_biasprm[:, 1:3], off.model.actuator_biasprm[:, 1:3] * s[i][:, None])
    cols = dict(on.extrinsics_layout)
    assert cols["motor_strength"] == 12 and on.spec.privileged_dim == 66
    off.close()
    on.close()


def test_frames_can_carry_the_previous_action():
    t = tasks.make("cartpole_balance_hist", 4, seed=0, overrides={"history_len": 2, "history_actions": True,
                                                                  "history_extrinsics": False})
    assert t.spec.frame_dim == 5 + 1
    obs, _ = t.reset()
    frames, _ = split_obs(t.spec, obs)
    np.testing.assert_array_equal(frames[..., 5], 0.0)  # no action before the first frame
    a = np.array([[0.5], [-0.25], [2.0], [np.nan]], np.float32)
    out = t.step(a)
    nxt, _ = split_obs(t.spec, out.next_obs)
    np.testing.assert_array_equal(nxt[:, -1, 5], [0.5, -0.25, 1.0, 0.0])  # as the task applied it: clipped, NaN -> 0
    np.testing.assert_array_equal(nxt[:, 0, 5], 0.0)
