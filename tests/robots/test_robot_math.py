"""Hand-computed checks of the robots' pure functions: actions, rotations, IK step, task success, wire format."""

from __future__ import annotations

import math

import numpy as np
import pytest

from unilab_jax.robots import ik, protocol, scenes
from unilab_jax.robots.experts import move_action, square_yaw
from unilab_jax.robots.interface import BadRequest, Health, RobotSpec, check_action
from unilab_jax.robots.manipulation import (
    SUCCESS_BONUS,
    BinGeometry,
    PegGeometry,
    PegInsertion,
    Reach,
    in_bin,
    peg_potential,
    peg_success,
    pick_place_potential,
    reach_potential,
    shaped_reward,
)
from unilab_jax.robots.serve import parse_faults
from unilab_jax.robots.sim import apply_delta, gripper_ctrl, gripper_opening, proprio_vector


def _spec(**kw) -> RobotSpec:
    base = dict(name="r", kind="franka", task="pick_place", proprio_dim=13, privileged_dim=18, cameras=(),
                image_shape=(64, 64, 3), control_hz=10.0, episode_length=100, max_delta_pos=0.03,
                max_delta_rot=0.25)
    return RobotSpec(**{**base, **kw})


def test_check_action_clips_and_rejects():
    assert check_action([2, -3, 0.5, 0, 0, 0, 1]).tolist() == [1, -1, 0.5, 0, 0, 0, 1]
    with pytest.raises(ValueError, match="shape"):
        check_action(np.zeros(6))
    with pytest.raises(ValueError, match="finite"):
        check_action([np.nan, 0, 0, 0, 0, 0, 0])


def test_spec_periods_and_round_trip():
    spec = _spec(speed=20.0, reset_seconds=2.0)
    assert spec.period_s == pytest.approx(0.005)
    assert spec.reset_wall_s == pytest.approx(0.1)
    assert _spec(speed=math.inf).period_s == 0.0
    assert RobotSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(ValueError, match="image_shape"):
        _spec(image_shape=(64, 64, 4))
    with pytest.raises(ValueError, match="health state"):
        Health("sleeping")


def test_rotation_helpers():
    q = ik.quat_from_rotvec([0.0, 0.0, math.pi / 2])
    assert q == pytest.approx([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
    assert ik.yaw_of_quat(q) == pytest.approx(math.pi / 2)
    # error from identity to q is q's rotation vector
    assert ik.quat_error(q, np.array([1.0, 0, 0, 0])) == pytest.approx([0, 0, math.pi / 2])
    assert ik.quat_error(q, q) == pytest.approx([0, 0, 0])
    # q and -q are the same rotation: the error takes the short way
    assert ik.quat_error(-q, q) == pytest.approx([0, 0, 0], abs=1e-12)
    assert square_yaw(math.radians(100)) == pytest.approx(math.radians(10))
    assert square_yaw(math.radians(-50)) == pytest.approx(math.radians(40))


def test_dls_step_matches_the_formula():
    jac = np.array([[1.0, 0.0], [0.0, 2.0]])
    err = np.array([1.0, 1.0])
    # J^T (J J^T + l^2 I)^-1 e with l = 1: [1/(1+1), 2/(4+1)]
    assert ik.dls_step(jac, err, 1.0) == pytest.approx([0.5, 0.4])


def test_apply_delta_scales_clips_and_rotates():
    quat = np.array(scenes.HOME_TCP_QUAT)
    pos, q = apply_delta(np.array([0.5, 0.0, 0.2]), quat, np.array([1, -0.5, 0, 0, 0, 1, 0.0]), 0.03, 0.25)
    assert pos == pytest.approx([0.53, -0.015, 0.2])
    assert ik.quat_error(q, quat) == pytest.approx([0, 0, 0.25])
    low, _ = apply_delta(np.array([0.5, 0.0, 0.01]), quat, np.array([0, 0, -1, 0, 0, 0, 0.0]), 0.03, 0.25)
    assert low[2] == pytest.approx(0.005)  # floor of the workspace


def test_gripper_mapping():
    franka, ur5e = scenes.ARMS["franka"], scenes.ARMS["ur5e"]
    assert gripper_ctrl(-1.0, franka) == 255.0 and gripper_ctrl(1.0, franka) == 0.0
    assert gripper_ctrl(-1.0, ur5e) == 0.0 and gripper_ctrl(0.0, ur5e) == 127.5
    assert gripper_opening(np.array([0.02]), franka) == pytest.approx(0.5)
    assert gripper_opening(np.array([0.8]), ur5e) == pytest.approx(0.0)


def test_proprio_layout():
    v = proprio_vector(np.array([1.0, 2, 3]), np.eye(3), np.array([4.0, 5, 6]), 0.25)
    assert v.tolist() == [1, 2, 3, 1, 0, 0, 0, 1, 0, 4, 5, 6, 0.25]


def test_peg_success_and_reward():
    g = PegGeometry()
    hole = np.array([0.5, 0.0, 0.05])
    assert peg_success(np.array([0.501, -0.001, 0.029]), hole, g)
    assert not peg_success(np.array([0.501, 0.0, 0.031]), hole, g)  # not deep enough
    assert not peg_success(np.array([0.512, 0.0, 0.0]), hole, g)  # outside the 11.5 mm half width
    assert peg_potential(np.array([0.5, 0.0, 0.03]), hole, g) == pytest.approx(1.0)
    # 5 cm straight above the bottom of the insertion: aligned, reaching 1 - tanh(0.5)
    assert peg_potential(np.array([0.5, 0.0, 0.08]), hole, g) == pytest.approx((1 + 1 - math.tanh(0.5)) / 2)
    # on the block's top 5 mm off the axis vs over the opening: alignment tells them apart (reaching: by 0.005)
    jammed = peg_potential(np.array([0.505, 0.0, 0.05]), hole, g)
    over = peg_potential(np.array([0.5, 0.0, 0.05]), hole, g)
    assert over - jammed == pytest.approx((math.tanh(10 * math.hypot(0.005, 0.02)) - math.tanh(0.2)
                                           + math.tanh(0.5)) / 2)
    assert over - jammed > 0.2


def test_reach_success_and_potential_read_the_plane_only():
    task = Reach("franka", dense_reward=True)
    target = np.array([0.45, 0.05, 0.0])
    state = np.concatenate([target, np.zeros(3)])
    assert task.success(state, np.array([0.46, 0.06, 0.3]))  # 1.4 cm away in the plane, at any height
    assert not task.success(state, np.array([0.471, 0.05, 0.0]))  # 2.1 cm: outside the 2 cm radius
    assert reach_potential(np.array([0.45, 0.05, 0.25]), target) == pytest.approx(1.0)
    assert task.potential(state, np.array([0.45, 0.15, 0.1])) == pytest.approx(1.0 - math.tanh(1.0))


def test_shaped_reward_pays_progress_and_success():
    assert shaped_reward(0.8, 0.5, False) == pytest.approx(0.3)
    assert shaped_reward(0.5, 0.8, False) == pytest.approx(-0.3)  # moving away costs what approaching paid
    assert shaped_reward(0.9, 0.9, True, bonus=10.0) == pytest.approx(10.0)
    hole = np.array([0.5, 0.0, 0.05])
    state = np.concatenate([[0.5, 0.0, 0.08], hole])  # tip 3 cm above the opening
    inserted = np.concatenate([[0.5, 0.0, 0.029], hole])
    sparse, dense = PegInsertion("franka"), PegInsertion("franka", dense_reward=True)
    assert sparse.reward(state, np.zeros(3), previous=0.2) == (0.0, False)
    assert sparse.reward(inserted, np.zeros(3), previous=0.2) == (1.0, True)
    r, success = dense.reward(state, np.zeros(3), previous=0.2)
    assert not success and r == pytest.approx((2 - math.tanh(0.5)) / 2 - 0.2)
    r, success = dense.reward(inserted, np.zeros(3), previous=0.9)
    assert success and r == pytest.approx(SUCCESS_BONUS + (2 - math.tanh(0.01)) / 2 - 0.9)


def test_finishing_beats_hovering_near_the_hole():
    """The episode ends on success. From a state of potential 0.5, at gamma 0.95 over the 100-step episode:
    hover 2 mm above the insertion's bottom (potential 1 - tanh(0.02)) for the remaining 99 steps, or go one
    more step and succeed. The potential itself as the reward (the former dense reward: potential + success)
    paid hovering 19.68 against 2.00 for finishing; the difference pays 0.49 against 10.50."""
    g, hole, gamma = PegGeometry(), np.array([0.5, 0.0, 0.05]), 0.95
    hover = peg_potential(np.array([0.5, 0.0, 0.032]), hole, g)
    done = peg_potential(np.array([0.5, 0.0, 0.029]), hole, g)
    discount = gamma ** np.arange(99)
    old_hover = float(np.sum(discount * hover))
    old_finish = done + 1.0
    assert old_hover == pytest.approx(19.68, abs=0.01) and old_finish == pytest.approx(2.00, abs=0.01)
    new_hover = shaped_reward(hover, 0.5, False) + float(np.sum(discount[1:] * shaped_reward(hover, hover, False)))
    new_finish = shaped_reward(done, 0.5, True)
    assert new_hover == pytest.approx(hover - 0.5) and new_finish == pytest.approx(SUCCESS_BONUS + done - 0.5)
    assert new_finish > 20 * new_hover


def test_in_bin():
    g = BinGeometry()
    b = np.array([0.48, -0.23, 0.0])
    assert in_bin(np.array([0.5, -0.2, 0.03]), b, g)
    assert not in_bin(np.array([0.5, -0.2, 0.06]), b, g)  # above the walls
    assert not in_bin(np.array([0.56, -0.2, 0.03]), b, g)  # 8 cm off-centre, walls at 7 cm


def test_pick_place_potential():
    g = BinGeometry()
    b = np.array([0.5, -0.2, 0.0])
    held_over_bin = np.array([0.5, -0.2, 0.1])
    assert pick_place_potential(held_over_bin, held_over_bin, b, g) == pytest.approx(1.0)
    # on the table, 0.1 m from the tcp: only the reaching term, 1 - tanh(1)
    obj = np.array([0.5, 0.1, 0.02])
    assert pick_place_potential(obj, obj + [0.0, 0.0, 0.1], b, g) == pytest.approx((1 - math.tanh(1.0)) / 3)


def test_move_action_is_proportional_and_clipped():
    spec = _spec()
    quat = np.array(scenes.HOME_TCP_QUAT)
    a = move_action(np.zeros(3), quat, np.array([0.015, -0.3, 0.0]), quat, 1.0, spec)
    assert a.tolist() == pytest.approx([0.5, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0])


def test_wire_format_round_trip_and_rejects():
    tree = {"a": np.arange(6, dtype=np.float32).reshape(2, 3), "img": np.zeros((4, 4, 3), np.uint8),
            "n": np.float64(1.5), "s": "x", "l": [1, True, None]}
    back = protocol.unpack(protocol.pack(tree))
    assert back["a"].dtype == np.float32 and back["a"].tolist() == tree["a"].tolist()
    assert back["img"].shape == (4, 4, 3) and back["n"] == 1.5 and back["l"] == [1, True, None]
    with pytest.raises(BadRequest, match="undecodable"):
        protocol.unpack(b"\xc1garbage")
    with pytest.raises(TypeError):
        protocol.pack({"o": np.array([object()])})
    with pytest.raises(BadRequest, match="a request must be a map"):
        protocol.parse_request([1, 2])
    with pytest.raises(BadRequest, match="non-empty client"):
        protocol.parse_request({"op": "step", "id": 1, "client": ""})


def test_parse_faults():
    assert parse_faults(["drop:0.5", "exit_after:3"]) == {"drop_reply_prob": 0.5, "exit_after_steps": 3}
    with pytest.raises(ValueError, match="bad --fault"):
        parse_faults(["explode:1"])
