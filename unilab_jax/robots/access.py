"""Who may do what on a robot server: the claim (owner, lease, secret token), per-client rate limits, and the
ZAP handler that admits CURVE clients by an allow-list of public keys (docs/ROBOTS.md, "Deploying a robot
server").

Ownership: a ``claim`` on a free robot returns a fresh secret token; every owner operation must carry it and,
on a keyed server, come from the same CURVE key (the ``User-Id`` the ZAP handler gave the connection). The
client's name is only a label (``health`` shows it): knowing it grants nothing. A claim that carries the
current token renews the lease (and may change its length); any other claim on a held robot is refused.
"""

from __future__ import annotations

import dataclasses
import hmac
import math
import secrets
import time

import zmq
from zmq.utils import z85

from unilab_jax.robots.interface import BadRequest, RobotClaimed

MAX_LEASE_S = 3600.0
ZAP_ENDPOINT = "inproc://zeromq.zap.01"  # where libzmq sends its authentication requests (ZAP, RFC 27)


def lease_seconds(value: object) -> float:
    """A request's ``lease_s``, checked: a finite number in (0, MAX_LEASE_S]."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise BadRequest(f"lease_s must be a finite number of seconds, got {value!r}")
    if not 0.0 < value <= MAX_LEASE_S:
        raise BadRequest(f"lease_s must be in (0, {MAX_LEASE_S:g}], got {value}")
    return float(value)


@dataclasses.dataclass
class Claim:
    name: str  # the client's label (shown by health; no authority)
    key: str  # the CURVE public key (Z85) it claimed with; "" on an unkeyed server
    token: str
    lease_s: float
    ends: float  # time.monotonic() when the lease runs out
    peer: bytes  # the routing id of the connection it last spoke on (its requests go first)


class Claims:
    """The one claim a robot can have."""

    def __init__(self, robot_name: str):
        self.robot_name = robot_name
        self.current: Claim | None = None

    def claim(self, name: str, key: str, token: str, peer: bytes, lease_s: float) -> Claim:
        now = time.monotonic()
        c = self.current
        if c is not None and now < c.ends and not self._matches(c, key, token):
            raise RobotClaimed(f"robot {self.robot_name!r} is claimed by client {c.name!r} "
                               f"(lease ends in {c.ends - now:.1f} s)")
        if c is None or not self._matches(c, key, token):
            c = self.current = Claim(name, key, secrets.token_urlsafe(24), lease_s, now + lease_s, peer)
        c.lease_s, c.ends, c.peer = lease_s, now + lease_s, peer
        return c

    def check_owner(self, name: str, key: str, token: str, peer: bytes) -> Claim:
        """The claim, renewed, if this request comes from its owner; else RobotClaimed."""
        c = self.current
        if c is None or not self._matches(c, key, token):
            holder = f"client {c.name!r}" if c else "nobody"
            raise RobotClaimed(f"client {name!r} does not hold robot {self.robot_name!r} (claimed by {holder}); "
                               "claim it first")
        c.ends, c.peer = time.monotonic() + c.lease_s, peer
        return c

    def expired(self) -> bool:
        """True once (and the claim is dropped) when the current lease has run out."""
        if self.current is not None and time.monotonic() > self.current.ends:
            self.current = None
            return True
        return False

    @staticmethod
    def _matches(c: Claim, key: str, token: str) -> bool:
        return hmac.compare_digest(c.token, token) and c.key == key


class RateLimiter:
    """Token buckets: ``rate`` requests per second with bursts of ``burst``, per identity and (``total_rate``)
    for everyone together. Identities idle for a minute are forgotten."""

    def __init__(self, rate: float, burst: float, total_rate: float):
        self.rate, self.burst, self.total_rate = rate, burst, total_rate
        self._buckets: dict[bytes, list[float]] = {}
        self._total = [total_rate, time.monotonic()]
        self._swept = time.monotonic()

    def allow(self, identity: bytes) -> bool:
        now = time.monotonic()
        if now - self._swept > 60.0:
            self._buckets = {k: b for k, b in self._buckets.items() if now - b[1] < 60.0}
            self._swept = now
        bucket = self._buckets.setdefault(identity, [self.burst, now])
        return (self._take(bucket, now, self.rate, self.burst)
                and self._take(self._total, now, self.total_rate, self.total_rate))

    @staticmethod
    def _take(bucket: list[float], now: float, rate: float, cap: float) -> bool:
        bucket[0] = min(cap, bucket[0] + (now - bucket[1]) * rate)
        bucket[1] = now
        if bucket[0] < 1.0:
            return False
        bucket[0] -= 1.0
        return True


class ZapHandler:
    """Answers libzmq's authentication requests for the sockets of ``ctx``: a CURVE client is admitted when its
    public key is in ``allowed`` (Z85), and its connection's ``User-Id`` is that key; everything else is
    refused (``denied`` counts it). Polled by the server's own loop, so no extra thread competes with it."""

    def __init__(self, ctx: zmq.Context, allowed: frozenset[bytes]):
        self.allowed = allowed
        self.denied = 0
        self.socket = ctx.socket(zmq.REP)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.bind(ZAP_ENDPOINT)

    def answer_pending(self) -> None:
        while True:
            try:
                msg = self.socket.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            version, request_id = (msg + [b"", b""])[:2]
            user = self._admit(msg)
            if user:
                self.socket.send_multipart([version, request_id, b"200", b"OK", user, b""])
            else:
                self.denied += 1
                self.socket.send_multipart([version, request_id, b"400", b"key not admitted", b"", b""])

    def _admit(self, msg: list[bytes]) -> bytes:
        """The client's Z85 public key when the request is a well-formed CURVE one of an admitted key, else b""."""
        if len(msg) != 7 or msg[0] != b"1.0" or msg[5] != b"CURVE" or len(msg[6]) != 32:
            return b""
        key = z85.encode(msg[6])
        return key if key in self.allowed else b""

    def close(self) -> None:
        self.socket.close(0)
