"""allegro_rotate: hand-computed reward terms, termination, per-episode objects and the evaluation metrics."""

from __future__ import annotations

import math

import numpy as np
import pytest

import tasks
from tasks import allegro_metric
from tasks import allegro_rotate as ar

DT = 0.05
CANON = np.array(ar.CANONICAL_POSE)
CONFIG = ar.default_config()


def _yaw(angle):
    return ar.yaw_quat(np.array([angle], dtype=np.float64))


def _terms(**kw):
    base = {"angvel": np.zeros((1, 3)), "linvel": np.zeros((1, 3)), "joint_pos": CANON[None].copy(),
            "joint_vel": np.zeros((1, 16)), "canonical": CANON, "torque": np.zeros((1, 16)),
            "done": np.array([False]), "clip": (-0.5, 0.5)}
    return ar.reward_terms(**{**base, **kw})


@pytest.mark.parametrize("turn,expected", [(0.01, 0.2), (0.02, 0.4), (0.05, 0.5), (-0.01, -0.2), (-0.1, -0.5)])
def test_rotate_is_the_clipped_finite_difference_yaw_rate(turn, expected):
    q0 = _yaw(0.3)
    q1 = _yaw(0.3 + turn)
    _, angvel = ar.object_motion(np.zeros((1, 3)), q1, np.zeros((1, 3)), q0, DT)
    np.testing.assert_allclose(angvel[0], [0.0, 0.0, turn / DT], atol=1e-9)
    assert _terms(angvel=angvel)["rotate"][0] == pytest.approx(expected)


def test_rotation_vector_of_a_tilt_and_of_a_sign_flipped_quaternion():
    # 0.2 rad about x: (cos 0.1, sin 0.1, 0, 0); -q is the same rotation.
    q = np.array([[math.cos(0.1), math.sin(0.1), 0.0, 0.0]])
    np.testing.assert_allclose(ar.rotation_vector(q), [[0.2, 0.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(ar.rotation_vector(-q), [[0.2, 0.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(ar.rotation_vector(np.array([[1.0, 0.0, 0.0, 0.0]])), [[0.0, 0.0, 0.0]])


def test_penalty_terms_by_hand():
    linvel, _ = ar.object_motion(np.array([[0.01, -0.02, 0.005]]), _yaw(0.0), np.zeros((1, 3)), _yaw(0.0), DT)
    np.testing.assert_allclose(linvel, [[0.2, -0.4, 0.1]])
    q = CANON[None].copy()
    q[0, :2] += [0.1, 0.2]
    tau = np.zeros((1, 16))
    tau[0, :2] = [0.5, -0.5]
    qvel_same, qvel_opposite = np.zeros((1, 16)), np.zeros((1, 16))
    qvel_same[0, :2] = [1.0, 1.0]  # tau . qvel = 0.5 - 0.5 = 0
    qvel_opposite[0, :2] = [1.0, -1.0]  # tau . qvel = 1.0
    t = _terms(linvel=linvel, joint_pos=q, torque=tau, joint_vel=qvel_opposite, done=np.array([True]))
    assert t["object_linvel"][0] == pytest.approx(0.7)  # |0.2| + |-0.4| + |0.1|
    assert t["pose_diff"][0] == pytest.approx(0.01 + 0.04)
    assert t["torque"][0] == pytest.approx(0.5)
    assert t["work"][0] == pytest.approx(1.0)
    assert t["fall"][0] == 1.0
    assert _terms(torque=tau, joint_vel=qvel_same)["work"][0] == pytest.approx(0.0)
    scaled = ar.scale_terms(t, ar.reward_scales(CONFIG))
    assert scaled["pose_diff"][0] == pytest.approx(-0.3 * 0.05)
    assert scaled["work"][0] == pytest.approx(-2.0)
    assert ar.total_reward(scaled)[0] == pytest.approx(-0.3 * 0.7 - 0.3 * 0.05 - 0.1 * 0.5 - 2.0 * 1.0 - 10.0)


def test_fall_below_the_palm_or_away_from_its_centre():
    rel = np.array([[0.0, 0.0, 0.02], [0.0, 0.0, -0.001], [0.08, 0.05, 0.02], [0.05, -0.05, 0.02]])
    assert ar.fell(rel, 0.09).tolist() == [False, True, True, False]  # hypot(0.08, 0.05) = 0.094


def test_targets_are_relative_and_clipped_to_the_joint_range():
    lower, upper = np.full(16, -0.2), np.full(16, 0.2)
    target = np.zeros((1, 16))
    target[0, 0] = 0.19
    a = np.ones((1, 16))
    out = ar.next_targets(target, a, 1 / 24, lower, upper)
    assert out[0, 0] == pytest.approx(0.2) and out[0, 1] == pytest.approx(1 / 24)


def test_object_fields_by_hand():
    active = np.array([[0.0, 1.0], [1.0, 0.0]])  # env 0 a box, env 1 a cylinder
    nominal = np.array([ar.NOMINAL_SIZE["cylinder"], ar.NOMINAL_SIZE["box"]])
    f = ar.object_fields(active, np.array([1.0, 0.5]), np.array([0.1, 0.2]), np.zeros((2, 3)), np.array([0.7, 0.9]),
                         nominal, ("cylinder", "box"))
    a, b, c = ar.NOMINAL_SIZE["box"]
    np.testing.assert_allclose(f["body_inertia"][0], np.array([b * b + c * c, a * a + c * c, a * a + b * b]) * 0.1 / 3)
    r, h = 0.015, 0.0125  # half the nominal cylinder
    np.testing.assert_allclose(f["body_inertia"][1], [0.2 * (3 * r * r + 4 * h * h) / 12] * 2 + [0.2 * r * r / 2])
    np.testing.assert_allclose(f["geom_pos"][0], [[0, 0, ar.PARKED], [0, 0, 0]])  # the cylinder is parked
    np.testing.assert_allclose(f["geom_size"][1, 0], [r, h, 0.0])
    np.testing.assert_allclose(f["geom_rbound"][1, 0], math.hypot(r, h))
    np.testing.assert_allclose(f["geom_aabb"][0, 1], [0, 0, 0, a, b, c])
    np.testing.assert_allclose(f["geom_friction"][1, :, 0], [0.9, 0.9])
    np.testing.assert_allclose(ar.shape_one_hot(active, ("cylinder", "box")), [[0, 1], [1, 0]])


def test_simulated_rotation_fall_and_metrics():
    """On the real simulation: a spun object earns the rotation term; an object put below the palm ends the
    episode with the fall penalty; the tracker's metrics follow."""
    task = tasks.make("allegro_rotate", 2, seed=0, overrides={"noise_level": 0.0})
    task.reset()
    tracker = allegro_metric.RotationTracker(task)
    zero = np.zeros((2, 16), np.float32)
    for _ in range(5):
        out = tracker.step(zero)
    assert not (out.terminated | out.truncated).any()
    np.testing.assert_allclose(out.next_obs[:, 32:], task.info["target"] - CANON, atol=1e-6)  # previous targets
    qpos, qvel = task.sim.qpos.copy(), task.sim.qvel.copy()
    qvel[0, 16 + 5] = 3.0  # env 0: the object spins about z (free joint angular velocity, body frame = world z)
    qpos[1, 18] = -0.05  # env 1: the object is below the palm
    task.sim.set_state(np.arange(2), qpos, qvel, ctrl=task.info["target"])
    task.info["obj_pos"], task.info["obj_quat"] = qpos[:, 16:19].copy(), qpos[:, 19:23].copy()
    out = tracker.step(zero)
    assert out.terminated.tolist() == [False, True]
    assert 0.0 < task.object_angvel_z[0] and out.reward_terms["rotate"][0] > 0.0
    assert out.reward_terms["fall"][1] == pytest.approx(-10.0) and out.reward_terms["fall"][0] == 0.0
    total = np.sum(np.stack(list(out.reward_terms.values())), axis=0)
    np.testing.assert_allclose(out.reward, total, rtol=1e-5, atol=1e-6)
    m = tracker.result()
    assert m["time_to_fall"] == pytest.approx((1.0 + 6 / 400) / 2)  # env 0 never fell, env 1 at step 6
    assert m["rotation_rate"] > 0.0 and m["rotate_reward"] > 0.0
    # both envs played 6 steps: the whole-episode rate is the alive-step rate x 6 / 400
    assert m["rotation_episode"] == pytest.approx(m["rotation_rate"] * 6 / 400)
    task.close()


def test_objects_are_redrawn_per_episode_in_each_envs_model():
    task = tasks.make("allegro_rotate", 4, seed=3, overrides={"episode_length": 2})
    task.reset()
    before = task.params.copy()
    masses = [m.body_mass[task.obj_body] for m in task.sim.models]
    np.testing.assert_allclose(masses, before[:, 0])
    assert len(set(np.round(before[:, 0], 6))) == 4  # each env its own object
    lo, hi = CONFIG.dr_mass
    assert ((before[:, 0] >= lo) & (before[:, 0] <= hi)).all()
    np.testing.assert_allclose(before[:, 6:8].sum(axis=1), 1.0)  # shape one-hot
    task.step(np.zeros((4, 16), np.float32))
    out = task.step(np.zeros((4, 16), np.float32))
    assert out.truncated.all()
    assert not np.isclose(task.params[:, 0], before[:, 0]).any()  # new objects after the reset
    np.testing.assert_allclose([m.body_mass[task.obj_body] for m in task.sim.models], task.params[:, 0])
    ext = task.extrinsics
    assert ext.shape == (4, ar.EXTRINSICS_DIM) and ext.dtype == np.float32
    np.testing.assert_allclose(ext[:, 8:], task.sim.qpos[:, 16:19] - [*ar.PALM_CENTER, ar.PALM_TOP], atol=1e-6)
    task.close()


def test_privileged_actor_reads_the_object_state_extrinsics():
    """``object_state_extrinsics`` appends the object's quaternion and finite-difference velocities to the
    extrinsics; ``actor_extrinsics`` ends the actor's observation with them; a reset zeroes the velocities."""
    task = tasks.make("allegro_rotate", 2, seed=0, overrides={"noise_level": 0.0, "episode_length": 3,
                                                              "object_state_extrinsics": True,
                                                              "actor_extrinsics": True})
    assert task.spec.obs_dim == 48 + 21 and task.spec.privileged_dim == 21
    obs, _ = task.reset()
    np.testing.assert_allclose(obs[:, 48:], task.extrinsics)
    np.testing.assert_array_equal(obs[:, 48 + 15:], 0.0)  # no velocity before a step
    task.step(np.zeros((2, 16), np.float32))
    qpos, qvel = task.sim.qpos.copy(), task.sim.qvel.copy()
    qvel[0, 16 + 5] = 3.0  # env 0 spins about z
    task.sim.set_state(np.arange(2), qpos, qvel, ctrl=task.info["target"])
    task.info["obj_pos"], task.info["obj_quat"] = qpos[:, 16:19].copy(), qpos[:, 19:23].copy()
    out = task.step(np.zeros((2, 16), np.float32))
    ext = task.extrinsics
    np.testing.assert_allclose(out.next_obs[:, 48:], ext, atol=1e-6)
    quat = task.sim.qpos[:, 19:23]
    np.testing.assert_allclose(ext[:, 11:15], quat * np.sign(quat[:, :1]), atol=1e-6)
    np.testing.assert_allclose(ext[:, 15:18], (task.sim.qpos[:, 16:19] - qpos[:, 16:19]) / task.dt, atol=1e-5)
    assert ext[0, 20] == pytest.approx(task.object_angvel_z[0], rel=1e-5) and ext[0, 20] > 0.3
    out = task.step(np.zeros((2, 16), np.float32))  # the time limit: both envs start over
    assert out.truncated.all()
    np.testing.assert_array_equal(out.obs[:, 48 + 15:], 0.0)
    np.testing.assert_array_equal(task.extrinsics[:, 15:], 0.0)
    task.close()


def test_reset_press_offsets_the_targets_not_the_joints():
    task = tasks.make("allegro_rotate", 3, seed=2, overrides={"reset_press": 0.25})
    obs, _ = task.reset()
    pose = task.sim.qpos[:, :16]
    assert np.abs(pose - CANON).max() <= CONFIG.reset_pose_noise + 1e-9  # the joints at the noisy canonical pose
    press = np.zeros(16)
    press[[2, 3, 6, 7, 10, 11]] = 0.25  # index, middle, ring: medial and distal
    np.testing.assert_allclose(task.info["target"] - pose, np.broadcast_to(press, (3, 16)), atol=1e-12)
    np.testing.assert_allclose(obs[:, 32:48], task.info["target"] - CANON, atol=1e-6)
    task.close()


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="shapes"):
        tasks.make("allegro_rotate", 1, overrides={"shapes": ("sphere",)})
    with pytest.raises(ValueError, match="multiple of sim_dt"):
        tasks.make("allegro_rotate", 1, overrides={"ctrl_dt": 0.052})


def test_history_variant_evaluates_through_the_variant():
    """``allegro_rotate_hist``'s tracker steps the variant (history observations), reads the wrapped task."""
    task = tasks.make("allegro_rotate_hist", 2, seed=0, overrides={"history_len": 3, "episode_length": 5})
    tracker = task.eval_tracker()
    task.reset()
    out = tracker.step(np.zeros((2, 16), np.float32))
    assert out.obs.shape == (2, task.spec.obs_dim) == (2, 3 * 48 + ar.EXTRINSICS_DIM)
    assert set(tracker.result()) == set(allegro_metric.RotationTracker.LOGGED)
    task.close()
    go1 = tasks.make("go1_joystick_flat_hist", 1, seed=0)
    assert not hasattr(go1, "eval_tracker")  # no tracker of its own: the walking metric applies
    go1.close()
