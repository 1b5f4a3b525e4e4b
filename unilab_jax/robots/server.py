"""A robot server: one process owns one robot and serves the Robot contract over ZeroMQ (ROUTER socket).

Clients (``robots.client.RobotClient``, DEALER sockets) send msgpack requests (``robots.protocol``).
Operations: ``spec``, ``health``, ``ping`` and ``estop`` are open to anyone (an emergency stop must
never be refused); ``claim`` takes the robot for one client id with a lease of ``lease_s`` seconds that
every request of the owner renews (``heartbeat`` does nothing else); ``reset``, ``step``,
``clear_estop`` and ``release`` need the claim. When a lease expires the robot is emergency-stopped
(holds still) and free for the next client.

A request that cannot be decoded, is larger than ``max_message_bytes`` or names an unknown op gets an
error reply (type BadRequest) and the server keeps serving. Injected faults (``FaultConfig``) make the
server drop replies, stop answering, or exit, like a crashed or unplugged robot controller.
"""

from __future__ import annotations

import dataclasses
import os
import threading
import time
from typing import Any

import numpy as np
import zmq

from unilab_jax.robots import protocol
from unilab_jax.robots.interface import BadRequest, Robot, RobotClaimed

OPEN_OPS = frozenset({"spec", "health", "ping", "estop", "claim"})
OWNER_OPS = frozenset({"reset", "step", "clear_estop", "release", "heartbeat"})


@dataclasses.dataclass(frozen=True)
class FaultConfig:
    """Injected faults. ``drop_reply_prob``: chance that a handled request gets no reply;
    ``stall_after_steps`` / ``exit_after_steps``: after that many steps the server stops answering
    (keeps the socket open) / exits at once with status 3 (-1: never)."""

    drop_reply_prob: float = 0.0
    stall_after_steps: int = -1
    exit_after_steps: int = -1

    def __post_init__(self):
        if not 0.0 <= self.drop_reply_prob <= 1.0:
            raise ValueError(f"drop_reply_prob must be in [0, 1], got {self.drop_reply_prob}")


@dataclasses.dataclass(frozen=True)
class ServerConfig:
    host: str = "127.0.0.1"
    port: int = 0  # 0: a free port chosen by the OS (see RobotServer.port)
    lease_s: float = 5.0
    max_message_bytes: int = 1 << 20
    poll_s: float = 0.05  # how often the loop checks leases and the stop flag
    faults: FaultConfig = FaultConfig()
    seed: int = 0


def step_to_wire(step) -> dict[str, Any]:
    return {"obs": step.obs, "reward": step.reward, "terminated": step.terminated, "truncated": step.truncated,
            "info": step.info}


class RobotServer:
    """Serves ``robot`` on ``tcp://host:port``. ``serve(stop)`` runs until ``stop`` (a threading.Event) is set."""

    def __init__(self, robot: Robot, config: ServerConfig = ServerConfig()):
        self.robot = robot
        self.config = config
        self._ctx = zmq.Context()
        self._sock = self._ctx.socket(zmq.ROUTER)
        self._sock.setsockopt(zmq.LINGER, 0)
        # Hard cap: zmq drops peers sending more than this (no reply possible); below it, oversized
        # requests get an error reply.
        self._sock.setsockopt(zmq.MAXMSGSIZE, 16 * config.max_message_bytes)
        if config.port:
            self._sock.bind(f"tcp://{config.host}:{config.port}")
            self.port = config.port
        else:
            self.port = self._sock.bind_to_random_port(f"tcp://{config.host}")
        self.owner: str | None = None
        self._lease_end = 0.0
        self._lease_s = config.lease_s
        self._dropped = 0
        self._steps = 0
        self._stalled = False
        self._rng = np.random.default_rng(config.seed)

    @property
    def address(self) -> str:
        return f"tcp://{self.config.host}:{self.port}"

    def serve(self, stop: threading.Event) -> None:
        """Answers requests until ``stop`` is set; then closes the socket."""
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        try:
            while not stop.is_set():
                self._expire_lease()
                if not dict(poller.poll(self.config.poll_s * 1000)):
                    continue
                frames = self._sock.recv_multipart()
                reply = self.handle(frames[-1])
                if reply is not None and not self._stalled:
                    self._sock.send_multipart([*frames[:-1], reply])
        finally:
            self._sock.close(0)
            self._ctx.term()

    def handle(self, payload: bytes) -> bytes | None:
        """One request -> its reply bytes (None: the reply is dropped by an injected fault)."""
        req_id = -1
        try:
            if len(payload) > self.config.max_message_bytes:
                raise BadRequest(f"message of {len(payload)} bytes exceeds the limit of "
                                 f"{self.config.max_message_bytes} bytes")
            op, req_id, client, args = protocol.parse_request(protocol.unpack(payload))
            result = self._dispatch(op, client, args)
            reply = protocol.ok(req_id, result)
        except Exception as e:  # noqa: BLE001  (every failure becomes an error reply; the server keeps serving)
            reply = protocol.error(req_id, e)
        return self._apply_faults(reply)

    # ---------------------------------------------------------------------------------------------
    def _dispatch(self, op: str, client: str, args: dict[str, Any]) -> Any:
        if op not in OPEN_OPS and op not in OWNER_OPS:
            raise BadRequest(f"unknown op {op!r}; known: {sorted(OPEN_OPS | OWNER_OPS)}")
        if op in OWNER_OPS:
            self._check_owner(client)
            result = self._owner_op(op, args)
            if self.owner == client:  # a reset may outlast a short lease
                self._lease_end = time.monotonic() + self._lease_s
            return result
        if op == "spec":
            return self.robot.spec.to_dict()
        if op == "health":
            return self._health()
        if op == "ping":
            return {"time": time.time()}
        if op == "estop":
            self.robot.estop()
            return self._health()
        return self._claim(client, args)

    def _owner_op(self, op: str, args: dict[str, Any]) -> Any:
        if op == "release":
            self.owner = None
            return {}
        if op == "heartbeat":
            return self._health()
        if op == "clear_estop":
            self.robot.clear_estop()
            return self._health()
        if op == "reset":
            seed = args.get("seed")
            if seed is not None and not isinstance(seed, int):
                raise BadRequest(f"seed must be an int or nil, got {seed!r}")
            return self.robot.reset(seed)
        action = args.get("action")
        if not isinstance(action, np.ndarray | list):
            raise BadRequest(f"step needs args.action (array of {self.robot.spec.action_dim}), got {type(action)}")
        self._steps += 1
        return step_to_wire(self.robot.step(action))

    def _claim(self, client: str, args: dict[str, Any]) -> dict[str, Any]:
        now = time.monotonic()
        if self.owner is not None and self.owner != client and now < self._lease_end:
            raise RobotClaimed(f"robot {self.robot.spec.name!r} is claimed by client {self.owner!r} "
                               f"(lease ends in {self._lease_end - now:.1f} s)")
        lease = float(args.get("lease_s", self.config.lease_s))
        if not 0.0 < lease <= 3600.0:
            raise BadRequest(f"lease_s must be in (0, 3600], got {lease}")
        self.owner, self._lease_s = client, lease
        self._lease_end = now + lease
        return {"lease_s": lease}

    def _check_owner(self, client: str) -> None:
        if self.owner != client:
            holder = f"client {self.owner!r}" if self.owner else "nobody"
            raise RobotClaimed(f"client {client!r} does not hold robot {self.robot.spec.name!r} "
                               f"(claimed by {holder}); claim it first")
        self._lease_end = time.monotonic() + self._lease_s

    def _expire_lease(self) -> None:
        if self.owner is not None and time.monotonic() > self._lease_end:
            self.owner = None
            self.robot.estop()

    def _health(self) -> dict[str, Any]:
        health = dataclasses.replace(self.robot.health(), dropped_messages=self._dropped, owner=self.owner or "")
        return health.to_dict()

    def _apply_faults(self, reply: bytes) -> bytes | None:
        f = self.config.faults
        if f.exit_after_steps >= 0 and self._steps >= f.exit_after_steps:
            os._exit(3)
        if f.stall_after_steps >= 0 and self._steps >= f.stall_after_steps:
            self._stalled = True
        if self._stalled or (f.drop_reply_prob > 0 and self._rng.random() < f.drop_reply_prob):
            self._dropped += 1
            return None
        return reply
