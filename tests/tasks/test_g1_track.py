"""G1 motion tracking: reward terms, termination and the start-sampling rule by hand; the committed clips (format,
IK targets met, generator reproduces them); the task on a real simulation (reference servo targets, clip
chaining, failure statistics, the evaluation metric)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

import tasks
from tasks import g1_motions, g1_track

SIGMAS = {"anchor_pos": 0.09, "anchor_ori": 0.16, "body_pos": 0.09, "body_ori": 0.16, "body_lin_vel": 1.0,
          "body_ang_vel": 9.87}
CLEAN = {"noise_level": 0.0, "domain_randomization": False}


def quat_x(angle):
    return np.array([math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0])


# --------------------------------------------------------------------------------------------------
# Hand-computed math
# --------------------------------------------------------------------------------------------------
def test_quaternion_helpers():
    q = g1_track.yaw_quat(np.array([0.7, math.pi / 2]))
    np.testing.assert_allclose(g1_track.heading(q), [0.7, math.pi / 2])
    np.testing.assert_allclose(g1_track.quat_rotate(q[1], np.array([1.0, 0.0, 0.5])), [0.0, 1.0, 0.5], atol=1e-12)
    assert g1_track.quat_angle(quat_x(0.4), np.array([1.0, 0, 0, 0])) == pytest.approx(0.4)
    assert g1_track.quat_angle(quat_x(0.4), -quat_x(0.4)) == pytest.approx(0.0, abs=1e-7)  # q and -q: same rotation
    np.testing.assert_allclose(g1_track.rotation_6d(q[1:]), [[0, 1, 0, -1, 0, 0]], atol=1e-12)


def test_anchor_relative_targets_move_the_reference_rigidly_onto_the_robot_anchor():
    # Robot anchor at (1, 2, 0.7) heading +90 deg; reference anchor at (0, 0, 0.8) heading 0; a reference body
    # 0.1 m ahead of and 0.3 m below its anchor, moving at +x 1 m/s, spinning about +x at 2 rad/s.
    yaw90 = g1_track.yaw_quat(np.array([math.pi / 2]))
    ident = np.array([[1.0, 0, 0, 0]])
    pos, quat, lin, ang = g1_track.anchor_relative_targets(
        np.array([[1.0, 2.0, 0.7]]), yaw90, np.array([[0.0, 0.0, 0.8]]), ident,
        np.array([[[0.1, 0.0, 0.5]]]), quat_x(0.3)[None, None], np.array([[[1.0, 0, 0]]]), np.array([[[2.0, 0, 0]]]))
    # Placed at the robot anchor's xy and the reference anchor's height, turned by 90 deg: 0.1 m ahead -> +y.
    np.testing.assert_allclose(pos, [[[1.0, 2.1, 0.5]]], atol=1e-12)
    np.testing.assert_allclose(lin, [[[0.0, 1.0, 0.0]]], atol=1e-12)
    np.testing.assert_allclose(ang, [[[0.0, 2.0, 0.0]]], atol=1e-12)
    np.testing.assert_allclose(quat, g1_track.quat_mul(yaw90, quat_x(0.3)[None])[None], atol=1e-12)


def test_tracking_terms_by_hand():
    # Two bodies, the anchor first. Robot anchor 0.3 m off the reference anchor and rolled 0.4 rad; body 1 is
    # 0.6 m from its target and rolled 0.4 rad from it; linear-velocity error 1 m/s on the anchor, angular 3 rad/s.
    ident = np.array([1.0, 0, 0, 0])
    body_pos = np.array([[[0.3, 0.0, 1.0], [0.6, 0.0, 0.5]]])
    target_pos = np.array([[[0.3, 0.0, 1.0], [0.0, 0.0, 0.5]]])
    body_quat = np.stack([quat_x(0.4), quat_x(0.4)])[None]
    target_quat = np.stack([quat_x(0.4), ident])[None]
    zeros = np.zeros((1, 2, 3))
    terms = g1_track.tracking_terms(
        anchor=0, body_pos=body_pos, body_quat=body_quat, body_lin=np.array([[[1.0, 0, 0], [0, 0, 0]]]),
        body_ang=np.array([[[0, 3.0, 0], [0, 0, 0]]]), ref_anchor_pos=np.array([[0.0, 0.0, 1.0]]),
        ref_anchor_quat=ident[None], target_pos=target_pos, target_quat=target_quat, target_lin=zeros,
        target_ang=zeros, action=np.array([[0.5, -0.5]]), last_act=np.zeros((1, 2)),
        joint_pos=np.array([[1.2, -1.5]]), soft_lower=np.array([-1.0, -1.0]), soft_upper=np.array([1.0, 1.0]),
        sigmas=SIGMAS)
    assert tuple(terms) == g1_track.REWARD_TERMS
    expected = {
        "anchor_pos": math.exp(-0.09 / 0.09), "anchor_ori": math.exp(-0.16 / 0.16),
        "body_pos": math.exp(-(0.36 / 2) / 0.09), "body_ori": math.exp(-(0.16 / 2) / 0.16),
        "body_lin_vel": math.exp(-(1.0 / 2) / 1.0), "body_ang_vel": math.exp(-(9.0 / 2) / 9.87),
        "action_rate": 0.5, "joint_limit": 0.2 + 0.5,
    }
    for k, v in expected.items():
        assert terms[k][0] == pytest.approx(v, rel=1e-9), k


def test_termination_thresholds():
    ident = np.array([[1.0, 0, 0, 0]])
    ref = np.array([[0.0, 0.0, 0.8]])

    def term(pos=(0.0, 0.0, 0.8), quat=ident, ee=(0.0, 0.0)):
        return bool(g1_track.tracking_terminated(np.array([pos]), quat, ref, ident, np.array([ee]),
                                                 np.zeros((1, 2)), 0.25, 0.8, 0.25)[0])

    assert not term()
    assert not term(pos=(5.0, 5.0, 0.8))  # the anchor's horizontal drift never terminates
    assert not term(pos=(0.0, 0.0, 0.56)) and term(pos=(0.0, 0.0, 0.54))
    # Tilt: projected-gravity z goes from -1 to -cos(angle); the error passes 0.8 at acos(0.2) = 78.5 deg.
    assert not term(quat=quat_x(math.radians(75))[None]) and term(quat=quat_x(math.radians(82))[None])
    assert not term(ee=(0.0, -0.24)) and term(ee=(0.0, 0.26))


def test_bin_probabilities_by_hand():
    # Clip 0 has 4 bins, clip 1 has 2. Failures spread to the bin before (spread_bins 2, weight 0.5), never
    # across clips: s = [0 + 0.5*2, 2 + 0, 0 + 0.5*1, 1 + 0 (next bin is clip 1's), 0, 0.5*0] = [1, 2, .5, 1, 0, 0].
    failures = np.array([0.0, 2.0, 0.0, 1.0, 0.0, 0.0])
    bin_clip = np.array([0, 0, 0, 0, 1, 1])
    p = g1_track.bin_probabilities(failures, bin_clip, uniform=0.2, spread_bins=2, spread_decay=0.5)
    s = np.array([1.0, 2.0, 0.5, 1.0, 0.0, 0.0])
    np.testing.assert_allclose(p, 0.2 / 6 + 0.8 * s / 4.5)
    assert p.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(g1_track.bin_probabilities(np.zeros(6), bin_clip, 0.2, 2, 0.5), np.full(6, 1 / 6))
    # One bin: no spreading, the failing bin takes all but the uniform share.
    p1 = g1_track.bin_probabilities(np.array([0.0, 0, 3.0, 0, 0, 0]), bin_clip, 0.1, 1, 0.5)
    np.testing.assert_allclose(p1, [0.1 / 6] * 2 + [0.1 / 6 + 0.9] + [0.1 / 6] * 3)


# --------------------------------------------------------------------------------------------------
# The committed clips
# --------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def model_and_stand():
    return g1_motions.g1_model()


@pytest.fixture(scope="module")
def clips():
    return {p.rsplit("/", 1)[1].removesuffix(".npz"): g1_motions.load_clip(p) for p in g1_motions.clip_paths()}


def test_clip_format(clips, model_and_stand):
    model, _ = model_and_stand
    assert set(clips) == set(g1_motions.CLIPS)
    joints = tuple(model.joint(j).name for j in range(1, model.njnt))
    first = next(iter(clips.values()))["qpos"][0]
    for name, c in clips.items():
        T = c["qpos"].shape[0]
        assert float(c["fps"]) == 50.0 and tuple(c["joint_names"]) == joints and len(joints) == 29
        assert tuple(c["body_names"]) == g1_motions.TRACKED_BODIES and str(c["anchor_body"]) == "torso_link"
        assert c["qpos"].shape == (T, 36) and c["qvel"].shape == (T, 35) and c["body_pos"].shape == (T, 14, 3)
        assert c["body_quat"].shape == (T, 14, 4) and c["body_lin_vel"].shape == c["body_ang_vel"].shape == (T, 14, 3)
        np.testing.assert_allclose(np.linalg.norm(c["qpos"][:, 3:7], axis=1), 1.0, atol=1e-5)
        lo, hi = model.jnt_range[1:, 0], model.jnt_range[1:, 1]
        assert ((c["qpos"][:, 7:] >= lo - 1e-5) & (c["qpos"][:, 7:] <= hi + 1e-5)).all(), name
        # Every clip starts and ends in the same standing pose (the task chains clips).
        np.testing.assert_allclose(c["qpos"][[0, -1], 7:], first[None, 7:].repeat(2, 0), atol=1e-4, err_msg=name)
        np.testing.assert_allclose(c["qpos"][[0, -1], 2], first[2], atol=1e-4)
        assert np.abs(c["qvel"][[0, -1]]).max() < 1e-3


def test_ik_meets_the_keyframe_targets(clips, model_and_stand):
    # Tolerances (measured worst case): pelvis 2.4 mm / 1 mrad, feet 0.8 mm / 28 mrad (the side step's feet at the
    # ankle's roll limit), hands 2 cm (weight 1 against 10 for pelvis and feet: the hop's arms-up keyframe).
    model, stand = model_and_stand
    ik = g1_motions.IKSolver(model, stand)
    for name, c in clips.items():
        targets, frames = g1_motions.target_trajectory(g1_motions.CLIPS[name]())
        np.testing.assert_array_equal(frames, c["keyframe_frames"])
        for f in frames:
            ik.d.qpos[:] = c["qpos"][f]
            mujoco.mj_kinematics(model, ik.d)
            mujoco.mj_comPos(model, ik.d)
            r = np.abs(ik.residuals({n: v[f] for n, v in targets.items()})[0])
            assert r[0:3].max() < 4e-3 and r[3:6].max() < 3e-3, (name, f, r[:6])
            assert r[[6, 7, 8, 12, 13, 14]].max() < 2e-3, (name, f, "feet position")
            assert r[[9, 10, 11, 15, 16, 17]].max() < 0.035, (name, f, "feet orientation")
            assert r[18:24].max() < 0.025, (name, f, "hands")


def test_clip_derived_bodies_match_forward_kinematics(clips, model_and_stand):
    model, _ = model_and_stand
    d = mujoco.MjData(model)
    ids = [model.body(b).id for b in g1_motions.TRACKED_BODIES]
    for c in clips.values():
        for f in range(0, c["qpos"].shape[0], 17):
            d.qpos[:] = c["qpos"][f]
            mujoco.mj_kinematics(model, d)
            np.testing.assert_allclose(c["body_pos"][f], d.xpos[ids], atol=2e-3)  # float16
            assert g1_track.quat_angle(c["body_quat"][f].astype(float), d.xquat[ids]).max() < 2e-3
        # Body velocities are those of the positions: central differences, within float16 and curvature.
        # (measured: mean 0.8-1.2 mm/s, max 0.04 m/s at the hop's take-off kink).
        err = np.abs((c["body_pos"][2:].astype(float) - c["body_pos"][:-2]) * 25.0 - c["body_lin_vel"][1:-1])
        assert err.mean() < 0.005 and err.max() < 0.1


def test_hop_flight_is_ballistic(clips):
    c = clips["hop"]
    lf = c["body_pos"][:, g1_motions.TRACKED_BODIES.index("left_ankle_roll_link"), 2].astype(float)
    airborne = np.flatnonzero(lf > lf[0] + 0.005)
    assert 8 <= airborne.size <= 11  # 0.2 s of flight at 50 fps
    z = c["qpos"][airborne, 2].astype(float)
    acc = np.diff(z, 2) * 50.0**2
    np.testing.assert_allclose(acc, -g1_motions.GRAVITY, atol=0.05)
    # The body is rigid in the air: joint velocities ~0 strictly inside the flight.
    assert np.abs(c["qvel"][airborne[2:-2], 6:]).max() < 0.05


def test_generator_reproduces_the_committed_squat(clips, model_and_stand):
    model, stand = model_and_stand
    made = g1_motions.make_clip(model, stand, g1_motions.CLIPS["squat"]())
    np.testing.assert_allclose(made["qpos"], clips["squat"]["qpos"], atol=1e-4)


def test_load_clip_rejects_a_bad_file(tmp_path, clips):
    bad = dict(clips["squat"])
    bad["body_pos"] = bad["body_pos"][:, :3]
    np.savez(tmp_path / "bad.npz", **bad)
    with pytest.raises(ValueError, match="body_pos has shape"):
        g1_motions.load_clip(str(tmp_path / "bad.npz"))
    stand = g1_motions.Keyframe(0.0, g1_motions.STAND)
    with pytest.raises(ValueError, match="unknown target"):
        g1_motions.target_trajectory([stand, g1_motions.Keyframe(0.2, {"tail": 1.0})])
    with pytest.raises(ValueError, match="fall on frames"):
        g1_motions.target_trajectory([stand, g1_motions.Keyframe(0.01)])


# --------------------------------------------------------------------------------------------------
# The task on a real simulation
# --------------------------------------------------------------------------------------------------
def test_reference_drives_the_servos_and_clips_chain():
    task = tasks.make("g1_track", 3, seed=0, overrides=CLEAN)
    cl = task.clips
    tracker = task.eval_tracker()
    obs, cobs = task.reset()
    # Evaluation starts: env i plays clip i mod n from its first frame, exactly on the reference.
    np.testing.assert_array_equal(task.clip, [0, 1, 2]) and np.testing.assert_array_equal(task.frame, 0)
    np.testing.assert_allclose(task.sim.qpos, cl.qpos[cl.start[:3]], atol=1e-12)
    # On the reference state the task's body sensors read the clip's body data (same frames, same conventions).
    s = task._state()
    for robot, ref, tol in (("body_pos", "ref_pos", 2e-3), ("body_lin", "ref_lin", 0.01),
                            ("body_ang", "ref_ang", 0.01)):
        np.testing.assert_allclose(s[robot], s[ref], atol=tol, err_msg=robot)
    assert g1_track.quat_angle(s["body_quat"], s["ref_quat"]).max() < 2e-3
    n = 29
    # Observation: reference joints ahead (frames +1 and +4) minus the default pose, then the anchor target.
    g1 = cl.index(task.clip, task.frame + 1)
    np.testing.assert_allclose(obs[:, 6 + 3 * n: 6 + 4 * n], cl.qpos[g1, 7:] - task.default_pose, atol=1e-5)
    np.testing.assert_allclose(obs[:, -1], 0.0)  # phase
    assert obs.shape[1] == 6 + 3 * n + 2 * n + 9 + 1 and cobs.shape[1] == obs.shape[1] + 6 + 2 * 3 * 14
    # A zero action servos to the reference's next frame.
    np.testing.assert_allclose(task._ctrl(np.zeros((3, n))), cl.qpos[g1, 7:])
    # Residual scale 0.5 x torque limit / kp: left knee 0.5 x 139 / 150, wrist yaw 0.5 x 5 / 20.
    joints = [task.policy_joint_names.index(j) for j in ("left_knee_joint", "left_wrist_yaw_joint")]
    np.testing.assert_allclose(task.action_scales[joints], [0.5 * 139 / 150, 0.5 * 5 / 20], rtol=1e-6)
    np.testing.assert_allclose(task._ctrl(np.ones((3, n))), cl.qpos[g1, 7:] + task.action_scales)
    # Put env 0 one frame before its clip's end (on the reference state there) and step: it finishes the clip
    # and goes on with a clip from frame 0, placed at the robot's pelvis (xy and heading).
    last = cl.start[0] + cl.length[0] - 1
    task.sim.set_state(np.array([0]), cl.qpos[last - 1][None], cl.qvel[last - 1][None])
    task.frame[0] = cl.length[0] - 2
    tracker.step(np.zeros((3, n), np.float32))
    assert task.clip_finished.tolist() == [True, False, False] and task.frame[0] == 0
    xy, yaw = task._root_in_world(cl.index(task.clip[:1], task.frame[:1]), np.array([0]))
    robot = task.sim.qpos[0]
    np.testing.assert_allclose(xy[0], robot[:2], atol=1e-9)
    np.testing.assert_allclose(math.remainder(yaw[0] - g1_track.heading(robot[3:7]), 2 * math.pi), 0.0, atol=1e-9)
    assert np.abs(robot[:2] - cl.qpos[last, :2]).max() < 0.01  # one servoed frame from the reference's end
    # Placing a frame whose pelvis is off the clip's origin (the side step's end: 0.1 m left) at a turned pose.
    side = cl.names.index("side_step")
    g_end = cl.index(np.array([side]), np.array([cl.length[side] - 1]))
    assert abs(cl.qpos[g_end[0], 1] - 0.1) < 0.01
    task._start_clip(np.array([1]), np.array([side]), np.array([cl.length[side] - 1]), np.array([[2.0, -1.0]]),
                     np.array([0.5]))
    xy, yaw = task._root_in_world(g_end, np.array([1]))
    np.testing.assert_allclose(xy, [[2.0, -1.0]], atol=1e-12)
    np.testing.assert_allclose(yaw, [0.5], atol=1e-12)
    result = tracker.result()
    assert result["clip_completion"] == pytest.approx(1 / 3) and 0 < result["body_pos_error"] < 0.1
    task.close()


def test_failures_raise_their_bins_sampling():
    task = tasks.make("g1_track", 4, seed=0, overrides={**CLEAN, "sampling_uniform": 0.0, "spread_bins": 1})
    task.reset()
    # Knock env 1 over (pelvis dropped 0.4 m): it terminates, and its clip bin's failure count rises by one.
    qpos = task.sim.qpos.copy()
    qpos[1, 2] -= 0.4
    task.sim.set_state(np.arange(4), qpos, task.sim.qvel.copy())
    clip, frame = int(task.clip[1]), int(task.frame[1]) + 1
    out = task.step(np.zeros((4, 29), np.float32))
    assert out.terminated[1]
    b = task.bin_offset[clip] + frame // task.bin_frames
    assert task.failures[b] == pytest.approx(1.0) and task.failures.sum() == pytest.approx(1.0)
    # With no uniform share and no spreading, every start is now drawn from that bin.
    task._reset_envs(np.arange(4))
    assert (task.clip == clip).all()
    assert ((task.frame >= task.bin_first[b]) & (task.frame <= task.bin_last[b])).all()
    task.close()
