"""Go1 joystick observation/reward math against values computed by hand from constructed inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tasks import go1_joystick
from tasks import go1_math as g
from tasks.floating_base import gravity_from_quat, quat_mul

DEFAULT = np.array([0.1, 0.9, -1.8, -0.1, 0.9, -1.8] * 2)


def row(*xs):
    return np.array([xs], dtype=np.float64)


def test_tracking_kernels():
    cmd = row(1.0, 0.5, 1.0)
    # lin: (1.0-0.8)^2 + (0.5-0.1)^2 = 0.04 + 0.16 = 0.2 -> exp(-0.2 / 0.25) = exp(-0.8)
    assert g.reward_tracking_lin_vel(cmd, row(0.8, 0.1, 0.3), 0.25)[0] == pytest.approx(math.exp(-0.8))
    # ang: (1.0-0.5)^2 = 0.25 -> exp(-1)
    assert g.reward_tracking_ang_vel(cmd, row(9.0, 9.0, 0.5), 0.25)[0] == pytest.approx(math.exp(-1.0))
    # perfect tracking -> 1
    assert g.reward_tracking_lin_vel(cmd, row(1.0, 0.5, -3.0), 0.25)[0] == pytest.approx(1.0)


def test_base_costs():
    assert g.cost_lin_vel_z(row(5.0, 5.0, 0.3))[0] == pytest.approx(0.09)
    assert g.cost_ang_vel_xy(row(0.1, -0.2, 7.0))[0] == pytest.approx(0.05)
    assert g.cost_orientation(row(0.1, -0.2, 0.97))[0] == pytest.approx(0.05)
    up = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, -0.1], [0.0, 0.0, 0.0]])
    assert g.terminated(up).tolist() == [False, True, False]


def test_regularisers():
    a = np.full((1, 12), 0.5)
    last = np.full((1, 12), 0.4)
    assert g.cost_action_rate(a, last)[0] == pytest.approx(12 * 0.01)
    tau = np.zeros((1, 12))
    tau[0, 0], tau[0, 1] = 3.0, -4.0
    assert g.cost_torques(tau)[0] == pytest.approx(5.0 + 7.0)  # |tau|_2 + |tau|_1
    qvel = np.zeros((1, 12))
    qvel[0, 0], qvel[0, 1] = -2.0, 0.5
    assert g.cost_energy(qvel, tau)[0] == pytest.approx(2.0 * 3.0 + 0.5 * 4.0)


def test_pose_stand_still_and_limits():
    q = (DEFAULT + 0.1)[None]
    weight = np.array(g.POSE_WEIGHT)
    # sum(0.01 * w) = 0.01 * 4 * (1 + 1 + 0.1) = 0.084
    assert g.reward_pose(q, DEFAULT, weight)[0] == pytest.approx(math.exp(-0.084))
    assert g.cost_stand_still(row(0.0, 0.0, 0.0), q, DEFAULT)[0] == pytest.approx(1.2)
    assert g.cost_stand_still(row(0.5, 0.0, 0.0), q, DEFAULT)[0] == 0.0
    lo, hi = -np.ones(12), np.ones(12)
    q = np.zeros((1, 12))
    q[0, 0], q[0, 5] = 1.2, -1.5
    assert g.cost_dof_pos_limits(q, lo, hi)[0] == pytest.approx(0.2 + 0.5)


def test_feet_bookkeeping_air_time_and_height():
    contact = np.array([[True, False, False, True]])
    last_contact = np.array([[False, False, True, False]])
    air = np.array([[0.28, 0.2, 0.0, 0.0]])
    peak = np.array([[0.05, 0.12, 0.0, 0.02]])
    feet_z = np.array([[0.03, 0.15, 0.02, 0.01]])
    first, air2, peak2 = g.feet_contact_update(contact, last_contact, air, peak, feet_z, 0.02)
    # filtered contact = contact | last = [T, F, T, T]; first contact needs air time > 0 -> [T, F, F, F]
    assert first.tolist() == [[True, False, False, False]]
    np.testing.assert_allclose(air2, [[0.30, 0.22, 0.02, 0.02]])
    np.testing.assert_allclose(peak2, [[0.05, 0.15, 0.02, 0.02]])
    cmd = row(1.0, 0.0, 0.0)
    # air time reward: (0.30 - 0.1) on the single first-contact foot
    assert g.reward_feet_air_time(cmd, air2, first)[0] == pytest.approx(0.2)
    assert g.reward_feet_air_time(row(0.0, 0.0, 0.0), air2, first)[0] == 0.0  # no reward at zero command
    # feet height: (0.05 / 0.1 - 1)^2 = 0.25 on the first-contact foot
    assert g.cost_feet_height(cmd, peak2, first, 0.1)[0] == pytest.approx(0.25)


def test_feet_slip_and_clearance():
    vel = np.zeros((1, 4, 3))
    vel[0, 0] = [3.0, 4.0, 9.0]  # |v_xy| = 5
    vel[0, 2] = [0.0, 1.0, 0.0]
    contact = np.array([[True, False, False, False]])
    assert g.cost_feet_slip(row(1.0, 0.0, 0.0), vel, contact)[0] == pytest.approx(25.0)
    assert g.cost_feet_slip(row(0.0, 0.0, 0.0), vel, contact)[0] == 0.0
    feet_z = np.array([[0.05, 0.3, 0.2, 0.1]])
    # |0.05 - 0.1| * sqrt(5) + |0.2 - 0.1| * sqrt(1)
    assert g.cost_feet_clearance(vel, feet_z, 0.1)[0] == pytest.approx(0.05 * math.sqrt(5.0) + 0.1)


def test_gravity_and_quaternions():
    s = math.sqrt(0.5)
    # Rotation of +90 deg about x: body z-axis points along world -y; gravity in the body frame is
    # R^T (0, 0, -1) = (0, -1, 0).
    np.testing.assert_allclose(gravity_from_quat(row(s, s, 0.0, 0.0))[0], [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(gravity_from_quat(row(1.0, 0.0, 0.0, 0.0))[0], [0.0, 0.0, -1.0])
    # 90 deg + 90 deg about z = 180 deg about z
    np.testing.assert_allclose(quat_mul(row(s, 0, 0, s), row(s, 0, 0, s))[0], [0, 0, 0, 1], atol=1e-12)


def test_total_reward_clip_and_scaling():
    terms = {"tracking_lin_vel": np.array([1.0, 0.0]), "termination": np.array([0.0, 1.0])}
    scales = {"tracking_lin_vel": 1.0, "termination": -1.0}
    scaled = g.scale_terms(terms, scales, 0.02)
    np.testing.assert_allclose(scaled["tracking_lin_vel"], [0.02, 0.0])
    np.testing.assert_allclose(scaled["termination"], [0.0, -0.02])
    np.testing.assert_allclose(g.total_reward(scaled), [0.02, 0.0])  # negative sum clipped to 0


def test_sample_command():
    old = row(1.0, 1.0, 1.0)
    new = g.sample_command(old, row(0.5, -0.5, 0.2), np.array([[True, False, True]]),
                           np.array([[True, True, False]]))
    np.testing.assert_allclose(new, [[0.5, 0.0, 1.0]])  # replaced, replaced-and-zeroed, kept


def test_actor_obs_layout_and_noise():
    M = 2
    lin, gyro, grav = np.full((M, 3), 1.0), np.full((M, 3), 2.0), np.full((M, 3), 3.0)
    qj = np.tile(DEFAULT, (M, 1)) + 0.5
    vj = np.full((M, 12), 4.0)
    last = np.full((M, 12), 5.0)
    cmd = np.full((M, 3), 6.0)
    noise = np.zeros((M, 33))
    noise[:, 0] = 0.1  # linvel x
    noise[:, 9] = -0.2  # first joint angle
    obs = g.actor_obs(lin, gyro, grav, qj, vj, last, cmd, DEFAULT, noise)
    assert obs.shape == (M, 48)
    expect = np.concatenate([[1.1, 1, 1], [2] * 3, [3] * 3, [0.3] + [0.5] * 11, [4] * 12, [5] * 12, [6] * 3])
    np.testing.assert_allclose(obs[0], expect)
    scales = g.noise_scales(go1_joystick.default_config())
    np.testing.assert_allclose(scales[[0, 3, 6, 9, 21]], [0.1, 0.2, 0.05, 0.03, 1.5])


def test_reward_math_runs_on_jax():
    """The same module-level functions work on jax arrays (the MJX variant reuses them)."""
    jnp = pytest.importorskip("jax.numpy")
    rng = np.random.default_rng(0)
    M = 3
    args = dict(
        command=rng.normal(size=(M, 3)), local_linvel=rng.normal(size=(M, 3)), gyro=rng.normal(size=(M, 3)),
        global_linvel=rng.normal(size=(M, 3)), global_angvel=rng.normal(size=(M, 3)),
        upvector=rng.normal(size=(M, 3)), joint_pos=rng.normal(size=(M, 12)),
        joint_vel=rng.normal(size=(M, 12)), default_pose=DEFAULT, pose_weight=np.array(g.POSE_WEIGHT),
        actuator_force=rng.normal(size=(M, 12)), action=rng.normal(size=(M, 12)),
        last_act=rng.normal(size=(M, 12)), done=rng.random(M) < 0.5, feet_vel=rng.normal(size=(M, 4, 3)),
        feet_z=rng.random((M, 4)), contact=rng.random((M, 4)) < 0.5, first_contact=rng.random((M, 4)) < 0.5,
        air_time=rng.random((M, 4)), swing_peak=rng.random((M, 4)), soft_lower=-np.ones(12),
        soft_upper=np.ones(12),
    )
    ref = g.reward_terms(**args, tracking_sigma=0.25, max_foot_height=0.1)
    jargs = {k: jnp.asarray(v.astype(np.float32) if v.dtype == np.float64 else v) for k, v in args.items()}
    out = g.reward_terms(**jargs, tracking_sigma=0.25, max_foot_height=0.1)
    assert set(out) == set(g.REWARD_TERMS)
    for k in ref:
        np.testing.assert_allclose(np.asarray(out[k]), ref[k], rtol=2e-5, atol=2e-5, err_msg=k)
