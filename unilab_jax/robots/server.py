"""A robot server: one process owns one robot and serves the Robot contract over ZeroMQ (ROUTER socket).

Clients (``robots.client.RobotClient``, DEALER sockets) send msgpack requests (``robots.protocol``).
Operations: ``spec``, ``health``, ``ping`` and ``estop`` are open to every admitted client (an emergency stop
must never be refused); ``claim`` takes a free robot and answers a secret token (``robots.access``) with a
lease of ``lease_s`` seconds that every request of the owner renews (``heartbeat`` does nothing else);
``reset``, ``step``, ``clear_estop``, ``release`` and ``heartbeat`` need the token (and, on a keyed server,
the key that claimed). When a lease expires the robot is emergency-stopped (holds still) and free again.

Keys (``key_file``: the server's ``.key_secret``; ``allow_dir``: the admitted clients' public ``.key`` files):
the socket speaks CURVE and admits only allow-listed keys; a server that listens on anything but loopback
refuses to start without them. The owner's requests are served first: every loop drains the socket, queues the
owner's messages ahead of everyone else's, and the others pass per-client and total rate limits (requests over
them are dropped unanswered and counted, except an ``estop``), so a flood of ``health`` requests or of
connections with unknown keys does not slow the owner's steps.

A request that cannot be decoded, is larger than ``max_message_bytes``, names an unknown op or has a malformed
field gets an error reply (type BadRequest) and the server keeps serving. Injected faults (``FaultConfig``) make
the server drop replies, stop answering, or exit, like a crashed or unplugged robot controller.
"""

from __future__ import annotations

import collections
import dataclasses
import ipaddress
import math
import os
import threading
import time
from typing import Any

import numpy as np
import zmq

from unilab_jax.robots import keys, protocol
from unilab_jax.robots.access import Claims, RateLimiter, ZapHandler, lease_seconds
from unilab_jax.robots.interface import BadRequest, Robot

OPEN_OPS = frozenset({"spec", "health", "ping", "estop", "claim"})
OWNER_OPS = frozenset({"reset", "step", "clear_estop", "release", "heartbeat"})
READ_OPS = frozenset({"spec", "health", "ping"})  # change nothing: the cached health stays valid
MAX_PENDING = 256  # queued requests of clients other than the owner; beyond: dropped (estops: twice as many)
MAX_DRAIN = 1024  # requests moved off the socket per loop (a flood faster than the drain cannot hold it there)


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


def is_loopback(host: str) -> bool:
    return host == "localhost" or (host != "*" and ipaddress.ip_address(host).is_loopback)


@dataclasses.dataclass(frozen=True)
class ServerConfig:
    host: str = "127.0.0.1"  # an IP address, localhost, or * (every interface)
    port: int = 0  # 0: a free port chosen by the OS (see RobotServer.port)
    lease_s: float = 5.0
    max_message_bytes: int = 1 << 20
    poll_s: float = 0.05  # how often the loop checks leases and the stop flag
    faults: FaultConfig = FaultConfig()
    seed: int = 0
    key_file: str = ""  # the server's NAME.key_secret ("": no CURVE, loopback only)
    allow_dir: str = ""  # folder of the admitted clients' public NAME.key files
    rate_hz: float = 20.0  # requests per second of each client other than the owner (bursts of rate_burst)
    rate_burst: float = 50.0
    total_rate_hz: float = 500.0  # requests per second of all clients but the owner together

    def __post_init__(self):
        if self.host not in ("localhost", "*"):
            try:
                ipaddress.ip_address(self.host)
            except ValueError:
                raise ValueError(f"host must be an IP address, localhost or *, got {self.host!r}") from None
        if not 0 <= self.port <= 65535:
            raise ValueError(f"port must be in [0, 65535], got {self.port}")
        if not (math.isfinite(self.lease_s) and 0 < self.lease_s <= 3600):
            raise ValueError(f"lease_s must be in (0, 3600], got {self.lease_s}")
        if self.max_message_bytes < 1024 or not self.poll_s > 0:
            raise ValueError(f"max_message_bytes must be >= 1024 and poll_s > 0, got {self.max_message_bytes}, "
                             f"{self.poll_s}")
        rates = (self.rate_hz, self.rate_burst, self.total_rate_hz)
        if not all(math.isfinite(r) and r >= 1 for r in rates):
            raise ValueError(f"rate_hz, rate_burst and total_rate_hz must be finite and >= 1, got {rates}")
        if bool(self.key_file) != bool(self.allow_dir):
            raise ValueError("a keyed server needs both key_file (its NAME.key_secret) and allow_dir (the clients' "
                             "public keys)")
        if not self.key_file and not is_loopback(self.host):
            raise ValueError(f"host {self.host} is reachable from the network: give the server a key pair and an "
                             "allow-list (serve --key=SERVER.key_secret --allow=CLIENT_KEYS_DIR; make keys with "
                             "python -m unilab_jax.robots.keys new NAME --dir DIR), or listen on 127.0.0.1")


def step_to_wire(step) -> dict[str, Any]:
    return {"obs": step.obs, "reward": step.reward, "terminated": step.terminated, "truncated": step.truncated,
            "info": step.info}


class RobotServer:
    """Serves ``robot`` on ``tcp://host:port``. ``serve(stop)`` runs until ``stop`` (a threading.Event) is set.
    Raises ValueError (naming the file or address) for unreadable keys or an address it cannot listen on."""

    def __init__(self, robot: Robot, config: ServerConfig = ServerConfig()):
        self.robot = robot
        self.config = config
        self.public_key = b""
        allowed = frozenset()
        if config.key_file:
            self.public_key, secret = keys.load_pair(config.key_file)
            allowed = keys.load_allowed(config.allow_dir)
        self._ctx = zmq.Context()
        self._zap = ZapHandler(self._ctx, allowed) if config.key_file else None
        self._sock = self._ctx.socket(zmq.ROUTER)
        self._sock.setsockopt(zmq.LINGER, 0)
        # Hard cap: zmq drops peers sending more than this (no reply possible); below it, oversized
        # requests get an error reply.
        self._sock.setsockopt(zmq.MAXMSGSIZE, 16 * config.max_message_bytes)
        self._sock.setsockopt(zmq.RCVHWM, 64)  # a client pipelining requests is held back by TCP beyond this
        if config.key_file:
            self._sock.curve_server = True
            self._sock.curve_secretkey, self._sock.curve_publickey = secret, self.public_key
            self._sock.zap_domain = b"robot"
        host = f"[{config.host}]" if ":" in config.host else config.host
        try:
            if config.port:
                self._sock.bind(f"tcp://{host}:{config.port}")
                self.port = config.port
            else:
                self.port = self._sock.bind_to_random_port(f"tcp://{host}")
        except zmq.ZMQError as e:
            self._close()
            raise ValueError(f"cannot listen on tcp://{host}:{config.port}: {e}") from None
        self._host = host
        self.claims = Claims(robot.spec.name)
        self._limiter = RateLimiter(config.rate_hz, config.rate_burst, config.total_rate_hz)
        self._owner_q: collections.deque = collections.deque()
        self._others: collections.deque = collections.deque()
        self._spec = robot.spec.to_dict()
        self._health_cache: tuple[tuple[int, int], dict[str, Any]] | None = None  # (counters it saw, health)
        self._dropped = 0
        self._rate_limited = 0
        self._steps = 0
        self._stalled = False
        self._rng = np.random.default_rng(config.seed)

    @property
    def address(self) -> str:
        return f"tcp://{self._host}:{self.port}"

    @property
    def owner(self) -> str | None:
        return self.claims.current.name if self.claims.current else None

    def serve(self, stop: threading.Event) -> None:
        """Answers requests until ``stop`` is set; then closes the sockets."""
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        if self._zap is not None:
            poller.register(self._zap.socket, zmq.POLLIN)
        try:
            while not stop.is_set():
                if self.claims.expired():
                    self.robot.estop()
                    self._health_cache = None
                if not self._owner_q and not self._others and not poller.poll(self.config.poll_s * 1000):
                    continue
                self._intake()
                queue = self._owner_q or self._others
                if queue:
                    self._answer(queue.popleft())
        finally:
            self._close()

    def handle(self, payload: bytes, peer: bytes = b"", user: str = "") -> bytes | None:
        """One request (from connection ``peer``, CURVE key ``user``) -> its reply bytes (None: the reply is
        dropped by an injected fault)."""
        req_id = -1
        try:
            if len(payload) > self.config.max_message_bytes:
                raise BadRequest(f"message of {len(payload)} bytes exceeds the limit of "
                                 f"{self.config.max_message_bytes} bytes")
            op, req_id, client, token, args = protocol.parse_request(protocol.unpack(payload))
            result = self._dispatch(op, client, token, args, peer, user)
            reply = protocol.ok(req_id, result)
        except Exception as e:  # noqa: BLE001  (every failure becomes an error reply; the server keeps serving)
            reply = protocol.error(req_id, e)
        return self._apply_faults(reply)

    # ---------------------------------------------------------------------------------------------
    def _intake(self) -> None:
        """Answers pending authentications, then moves every waiting request into the owner's queue or the
        others' (rate-limited, bounded)."""
        if self._zap is not None:
            self._zap.answer_pending()
        owner = self.claims.current
        for _ in range(MAX_DRAIN):
            try:
                frames = self._sock.recv_multipart(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                return
            if owner is not None and frames[0].bytes == owner.peer:
                self._owner_q.append(frames)
                continue
            identity = self._user(frames[-1]).encode() or frames[0].bytes
            if len(self._others) < MAX_PENDING and self._limiter.allow(identity):
                self._others.append(frames)
            elif len(self._others) < 2 * MAX_PENDING and _is_estop(frames[-1].bytes):
                self._others.appendleft(frames)  # a safety stop is not dropped for the rate limit
            else:
                self._rate_limited += 1

    def _answer(self, frames: list[zmq.Frame]) -> None:
        reply = self.handle(frames[-1].bytes, frames[0].bytes, self._user(frames[-1]))
        if reply is not None and not self._stalled:
            self._sock.send_multipart([*frames[:-1], reply])

    def _user(self, frame: zmq.Frame) -> str:
        """The CURVE public key (Z85) the ZAP handler admitted this message's connection with; "" unkeyed."""
        return frame.get("User-Id") if self._zap is not None else ""

    def _dispatch(self, op: str, client: str, token: str, args: dict[str, Any], peer: bytes, user: str) -> Any:
        if op not in OPEN_OPS and op not in OWNER_OPS:
            raise BadRequest(f"unknown op {op!r}; known: {sorted(OPEN_OPS | OWNER_OPS)}")
        if op not in READ_OPS:
            self._health_cache = None
        if op in OWNER_OPS:
            self.claims.check_owner(client, user, token, peer)
            return self._owner_op(op, args)
        if op == "spec":
            return self._spec
        if op == "health":
            return self._health()
        if op == "ping":
            return {"time": time.time()}
        if op == "estop":
            self.robot.estop()
            return self._health()
        lease = lease_seconds(args.get("lease_s", self.config.lease_s))
        claim = self.claims.claim(client, user, token, peer, lease)
        return {"lease_s": lease, "token": claim.token}

    def _owner_op(self, op: str, args: dict[str, Any]) -> Any:
        if op == "release":
            self.claims.current = None
            return {}
        if op == "heartbeat":
            return self._health()
        if op == "clear_estop":
            self.robot.clear_estop()
            return self._health()
        if op == "reset":
            seed = args.get("seed")
            if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
                raise BadRequest(f"seed must be a non-negative int or nil, got {seed!r}")
            return self.robot.reset(seed)
        action = args.get("action")
        if not isinstance(action, np.ndarray | list) or np.asarray(action).dtype.kind not in "biuf":
            raise BadRequest(f"step needs args.action (array of {self.robot.spec.action_dim} numbers), "
                             f"got {type(action).__name__}")
        self._steps += 1
        return step_to_wire(self.robot.step(action))

    def _health(self) -> dict[str, Any]:
        """The robot's health with the server's counters; cached until an operation or a counter changes it."""
        stamp = (self._rate_limited, self._zap.denied if self._zap else 0)
        if self._health_cache is None or self._health_cache[0] != stamp:
            h = self.robot.health()
            counts = {"rate_limited": stamp[0], "denied": stamp[1]}
            self._health_cache = stamp, dataclasses.replace(h, dropped_messages=self._dropped, owner=self.owner or "",
                                                            limit_hits={**h.limit_hits, **counts}).to_dict()
        return self._health_cache[1]

    def _apply_faults(self, reply: bytes) -> bytes | None:
        f = self.config.faults
        if f.exit_after_steps >= 0 and self._steps >= f.exit_after_steps:
            os._exit(3)
        if f.stall_after_steps >= 0 and self._steps >= f.stall_after_steps:
            self._stalled = True
        if self._stalled or (f.drop_reply_prob > 0 and self._rng.random() < f.drop_reply_prob):
            self._dropped += 1
            self._health_cache = None
            return None
        return reply

    def _close(self) -> None:
        self._sock.close(0)
        if self._zap is not None:
            self._zap.close()
        self._ctx.term()


def _is_estop(payload: bytes) -> bool:
    try:
        msg = protocol.unpack(payload)
    except BadRequest:
        return False
    return isinstance(msg, dict) and msg.get("op") == "estop"
