"""Safety limits the robot enforces whatever it is commanded (robots.limits, issue #34): the measured tcp pose
never leaves the workspace box or the orientation cone under the worst actions, the joint step is bounded,
contact force and tcp speed trigger protective stops, and every hit is counted."""

from __future__ import annotations

import numpy as np
import pytest

from unilab_jax.robots import ik, limits
from unilab_jax.robots.interface import RobotEstopped, is_protective_stop
from unilab_jax.robots.sim import SimConfig, SimRobot

LIMITS = limits.SafetyLimits()
ROTATE_X = [0, 0, 0, 1, 0, 0, 0]  # before the cone: the tcp left the box on 77 of 99 steps from reset(seed=0)


def oscillate(t: int) -> list[float]:
    return list(np.array([1, -1, 1, 1, -1, 1, 1.0]) * (1 if (t // 3) % 2 else -1))


WORST = {
    "rotate_x": lambda t: ROTATE_X,
    "rotate_-y": lambda t: [0, 0, 0, 0, -1, 0, 0],
    "translate+rotate": lambda t: [1, 1, 1, 1, 1, 1, 0],
    "down+rotate": lambda t: [-1, -1, -1, 1, -1, -1, 1],
    "oscillate": oscillate,
}


def robot(arm: str = "franka", **limit_kw) -> SimRobot:
    r = SimRobot(SimConfig(arm=arm, cameras=(), speed=float("inf"), reset_seconds=0.0,
                           limits=limits.SafetyLimits(**limit_kw)))
    r.reset(seed=0)
    return r


@pytest.mark.parametrize("arm,pattern", [("franka", name) for name in WORST] + [("ur5e", "rotate_x"),
                                                                                ("ur5e", "translate+rotate")])
def test_worst_actions_never_take_the_tcp_out_of_the_box_or_cone(arm, pattern):
    r = robot(arm)
    low, high = np.array(LIMITS.box_low), np.array(LIMITS.box_high)
    worst_out, worst_tilt = 0.0, 0.0
    for t in range(200):
        step = r.step(np.array(WORST[pattern](t), np.float32))  # a protective stop would raise on the next one
        pos, quat = step.obs["privileged"][:3].astype(float), step.obs["privileged"][3:7].astype(float)
        worst_out = max(worst_out, float(np.max(np.maximum(low - pos, pos - high))))
        worst_tilt = max(worst_tilt, np.degrees(limits.tilt(quat)))
        if step.terminated or step.truncated:
            r.reset()
    hits = r.health().limit_hits
    print(f"{arm} {pattern}: worst distance outside the box {worst_out * 1e3:.1f} mm (negative: inside), tilt "
          f"{worst_tilt:.1f} deg; limit hits {hits}")
    assert worst_out <= 0.0 and worst_tilt <= LIMITS.cone_deg + 10.0  # measured: 63.4 degrees at most
    assert hits["pose"] == 0 and r.health().state == "ok"
    clamped = hits["orientation"] if "rotate" in pattern else hits["joint_velocity"]
    assert clamped > 0  # the limit was exercised, not merely never reached


def test_joint_targets_move_at_most_max_joint_speed_per_period():
    r = robot(max_joint_speed=1.0)
    max_step = 1.0 / r.config.control_hz
    for t in range(60):
        q_before = r.data.qpos[r.ix.qpos].copy()
        r.step(np.array([0, 0, 0, 0, 0, 1, 0] if t % 20 < 10 else oscillate(t), np.float32))
        assert np.max(np.abs(r.data.ctrl[r.ix.ctrl] - q_before)) <= max_step + 1e-9
    assert r.health().limit_hits["joint_velocity"] > 0


@pytest.mark.parametrize("limit,action,detail", [
    ({"max_force": 50.0}, [0, 0, -1, 1, 0, 0, 1], "contact force"),  # the tilted hand pressed on the table
    ({"max_tcp_speed": 0.05}, [1, 0, 0, 0, 0, 0, 0], "tcp speed"),
])
def test_force_and_tcp_speed_limits_stop_the_robot_until_cleared(limit, action, detail):
    r = robot(**limit)
    with pytest.raises(RobotEstopped, match=f"protective stop: {detail}") as e:
        for _ in range(60):
            r.step(np.array(action, np.float32))
    assert is_protective_stop(e.value)  # what a robot task's StepInterrupted.stopped reads
    health = r.health()
    name = "force" if "max_force" in limit else "tcp_speed"
    assert health.state == "estopped" and health.limit_hits[name] >= 1 and detail in health.detail
    r.clear_estop()
    assert r.health().state == "ok" and r.health().detail == ""
    r.step(np.zeros(7, np.float32))  # holding still is allowed again


def test_clamp_to_cone_limit_joint_step_and_violation():
    down = np.array([0.0, 1.0, 0.0, 0.0])  # the home orientation: tcp pointing down
    assert limits.tilt(down) == pytest.approx(0.0, abs=1e-9)
    tilted = ik.quat_mul(ik.quat_from_rotvec([1.2, 0, 0]), down)
    q, clamped = limits.clamp_to_cone(tilted, np.radians(30))
    assert clamped and np.degrees(limits.tilt(q)) == pytest.approx(30.0)
    assert ik.quat_error(q, tilted) == pytest.approx([np.radians(30) - 1.2, 0, 0], abs=1e-9)  # tilted back only
    same, clamped = limits.clamp_to_cone(down, np.radians(30))
    assert not clamped and same is down
    q, limited = limits.limit_joint_step(np.zeros(3), np.array([0.4, -0.1, 0.0]), 0.2)
    assert limited and q == pytest.approx([0.2, -0.05, 0.0])
    assert LIMITS.violation(np.array([0.5, 0.0, 0.2]), down) == 0.0
    assert LIMITS.violation(np.array([0.83, 0.0, 0.2]), down) == pytest.approx(0.03)
    assert LIMITS.violation(np.array([0.83, 0.0, 0.2]), down, slack=0.02) == pytest.approx(0.01)
    assert LIMITS.violation(np.array([0.5, 0.0, 0.2]), tilted) == pytest.approx(1.2 - np.radians(60))
    with pytest.raises(ValueError, match="box_low"):
        limits.SafetyLimits(box_low=(1.0, 0, 0), box_high=(0.5, 1, 1))
