"""Robot server + client: claims and leases, error replies, disconnects, restarts, faults, camera images."""

from __future__ import annotations

import time

import numpy as np
import pytest
import zmq
from inprocess_server import thread_server

from unilab_jax.robots import protocol
from unilab_jax.robots.client import RobotClient, query
from unilab_jax.robots.experts import make_expert
from unilab_jax.robots.interface import RobotClaimed, RobotDisconnected
from unilab_jax.robots.server import FaultConfig

HOLD = np.array([0.0, 0, 0, 0, 0, 0, -1.0], dtype=np.float32)
MOVE = np.array([0.0, 1.0, -1.0, 0, 0, 0.5, 1.0], dtype=np.float32)
FAST = ("--speed=20", "--reset_s=0.1", "--cameras=none")


def _raw_call(address: str, payload: bytes, timeout_s: float = 5.0) -> dict:
    ctx = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    try:
        sock.connect(address)
        sock.send(payload)
        assert sock.poll(timeout_s * 1000), "no reply"
        return protocol.unpack(sock.recv())
    finally:
        sock.close(0)
        ctx.term()


def test_malformed_and_oversized_messages_get_error_replies():
    with thread_server(max_message_bytes=4096) as server:
        bad = _raw_call(server.address, b"\xc1 not msgpack")
        assert not bad["ok"] and bad["error"]["type"] == "BadRequest" and "undecodable" in bad["error"]["message"]
        not_map = _raw_call(server.address, protocol.pack([1, 2, 3]))
        assert "must be a map" in not_map["error"]["message"]
        unknown = _raw_call(server.address, protocol.request("fly", 7, "c"))
        assert unknown["id"] == 7 and "unknown op" in unknown["error"]["message"]
        big = _raw_call(server.address, protocol.request("ping", 8, "c", {"pad": b"x" * 10_000}))
        assert big["error"]["type"] == "BadRequest" and "exceeds the limit of 4096 bytes" in big["error"]["message"]
        token = _raw_call(server.address, protocol.request("claim", 9, "c"))["result"]["token"]
        wrong = _raw_call(server.address, protocol.request("step", 10, "c", {"action": [1.0, 2.0]}, token))
        assert wrong["error"]["type"] == "ValueError" and "shape" in wrong["error"]["message"]
        # still serving
        assert _raw_call(server.address, protocol.request("release", 11, "c", None, token))["ok"]
        with RobotClient(server.address, client_id="after") as robot:
            robot.reset(seed=0)
            assert robot.step(HOLD).obs["proprio"].shape == (13,)


def test_second_client_is_refused_until_release_or_lease_expiry(client):
    with thread_server() as server:
        first = client(server.address, client_id="first", lease_s=0.6, heartbeat_s=0.1)
        first.connect()
        second = client(server.address, client_id="second", timeout_s=1.0)
        with pytest.raises(RobotClaimed, match="claimed by client 'first'"):
            second.connect()
        time.sleep(1.0)  # the heartbeat keeps the lease alive while the first client idles
        with pytest.raises(RobotClaimed):
            second.connect()
        health = second.health()  # health and estop stay open to everyone
        assert health.state == "ok" and health.owner == "first"
        spec, health = query(server.address)
        assert spec.name == "franka_pick_place" and health.owner == "first"
        second.estop()
        assert first.health().state == "estopped"
        first.clear_estop()
        first.close()  # releases
        second.connect()
        second.reset(seed=0)
        second.step(HOLD)
        second.close()

        quiet = client(server.address, client_id="quiet", lease_s=0.3, heartbeat_s=0)
        quiet.connect()
        quiet.reset(seed=0)
        time.sleep(0.6)  # no heartbeat: the lease ends and the arm is stopped
        with RobotClient(server.address, client_id="next") as nxt:
            assert nxt.health().state == "estopped"
            nxt.reset(seed=1)
            nxt.step(HOLD)
        with pytest.raises(RobotClaimed, match="does not hold"):
            quiet.step(HOLD)
        quiet.close()


def test_dropped_reply_raises_robot_disconnected(client):
    with thread_server(faults=FaultConfig(drop_reply_prob=1.0)) as server:
        robot = client(server.address, timeout_s=0.3, heartbeat_s=0)
        t = time.perf_counter()
        with pytest.raises(RobotDisconnected, match="did not answer 'spec'"):
            robot.connect()
        assert time.perf_counter() - t < 2.0  # the 0.3 s timeout, plus slack for a loaded machine
        assert robot.health().state == "disconnected"
        robot.close()


def test_stalled_server_raises_robot_disconnected(client):
    with thread_server(faults=FaultConfig(stall_after_steps=2)) as server:
        robot = client(server.address, timeout_s=0.3, heartbeat_s=0)
        robot.connect()
        robot.reset(seed=0)
        robot.step(HOLD)
        with pytest.raises(RobotDisconnected, match="did not answer 'step'"):
            robot.step(HOLD)
        assert robot.health().state == "disconnected"
        assert robot.health().dropped_messages >= 2  # the step and the first health call
        robot.close()


def test_killed_server_disconnects_client_promptly_and_restart_accepts_a_new_client(serve, client):
    server = serve("--robot=franka", "--task=pick_place", "--port=0", *FAST)
    robot = client(server.address, timeout_s=0.5, heartbeat_s=0.05)
    robot.connect()
    robot.reset(seed=0)
    for _ in range(3):
        robot.step(MOVE)
    server.kill()
    time.sleep(0.1)  # a heartbeat is now waiting for its reply: the step's deadline includes that wait
    t = time.perf_counter()
    with pytest.raises(RobotDisconnected):
        robot.step(MOVE)
    waited = time.perf_counter() - t
    print(f"disconnect detected after {waited * 1e3:.0f} ms")
    assert waited < 2.0  # the 0.5 s timeout (+ the heartbeat's wait), plus slack for a loaded machine
    assert robot.health().state == "disconnected"
    with pytest.raises(RobotDisconnected):
        query(server.address, timeout_s=0.3)

    restarted = serve("--robot=franka", "--task=pick_place", f"--port={server.port}", *FAST)
    with RobotClient(restarted.address, timeout_s=2.0) as fresh:
        fresh.reset(seed=0)
        assert fresh.step(MOVE).obs["proprio"].shape == (13,)
        assert fresh.health().steps == 1
    robot.connect()  # the old client comes back too, once the new one has released the robot
    robot.reset(seed=1)
    robot.step(MOVE)
    assert robot.health().state == "ok"
    robot.close()
    assert restarted.stop() == 0


def test_expert_episode_over_the_wire(serve):
    server = serve("--robot=ur5e", "--task=pick_place", "--port=0", "--latency_ms=20", "--jitter_ms=5", *FAST)
    with RobotClient(server.address) as robot:
        expert = make_expert(robot.spec)
        obs = robot.reset(seed=3)
        for _ in range(robot.spec.episode_length):
            step = robot.step(expert(obs))
            obs = step.obs
            if step.terminated or step.truncated:
                break
        assert step.terminated and step.info["success"] and step.reward == 1.0
        health = robot.health()
    assert health.steps == step.info["t"] and health.resets == 1 and health.state == "ok"


def test_injected_exit_fault_ends_the_server_mid_episode(serve):
    server = serve("--robot=ur5e", "--task=peg_insertion", "--port=0", "--fault=exit_after:2", *FAST)
    with RobotClient(server.address, timeout_s=0.5) as robot:
        robot.reset(seed=0)
        robot.step(HOLD)
        with pytest.raises(RobotDisconnected):
            robot.step(HOLD)
    assert server.proc.wait(10) == 3


@pytest.mark.parametrize("arm", ["franka", "ur5e"])
def test_camera_images_through_the_server(serve, gl_backend, arm):
    server = serve(f"--robot={arm}", "--task=pick_place", "--port=0", "--speed=20", "--reset_s=0.1",
                   "--image_size=64", env={"MUJOCO_GL": gl_backend})
    with RobotClient(server.address, timeout_s=5.0) as robot:
        assert robot.spec.cameras == ("front", "wrist") and robot.spec.image_shape == (64, 64, 3)
        obs = robot.reset(seed=0)
        frames = [obs]
        t = time.perf_counter()
        for _ in range(3):
            frames.append(robot.step(MOVE).obs)
        per_step = (time.perf_counter() - t) / 3
    print(f"{arm}: step with 2 cameras (64 px, {gl_backend}) {per_step * 1e3:.0f} ms over the wire")
    for cam in ("front", "wrist"):
        for f in frames:
            assert f[cam].dtype == np.uint8 and f[cam].shape == (64, 64, 3)
        assert frames[0][cam].std() > 5  # not a blank frame
        diff = np.abs(frames[-1][cam].astype(int) - frames[0][cam].astype(int)).mean()
        assert diff > 1.0, f"{cam} image did not change while the arm moved ({diff})"
