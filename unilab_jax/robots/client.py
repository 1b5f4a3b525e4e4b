"""``RobotClient``: the Robot contract over the network, talking to a ``robots.server`` process.

::

    with RobotClient("tcp://127.0.0.1:5555") as robot:    # connect: fetch the spec, claim the robot
        obs = robot.reset()
        step = robot.step(np.zeros(7, np.float32))

Every call waits at most ``timeout_s`` plus the time the operation takes by contract (a control
period for ``step``, ``spec.reset_wall_s`` for ``reset``); a server that does not answer in time makes
the call raise ``RobotDisconnected`` and the client reports ``health().state == "disconnected"``
until the next successful call. ``heartbeat_s`` (default ``lease_s / 3``) runs a background thread
that renews the claim while the caller is busy elsewhere (e.g. training between episodes). The claim's
secret token (``robots.access``) goes with every owner operation. ``keys`` (``robots.keys.ClientKeys``: the
client's pair and the server's public key) are needed for a keyed server, which stays silent for clients it
does not admit (the call then raises RobotDisconnected).
"""

from __future__ import annotations

import dataclasses
import itertools
import threading
import time
import uuid
from typing import Any

import numpy as np
import zmq

from unilab_jax.robots import protocol
from unilab_jax.robots.interface import Health, Robot, RobotDisconnected, RobotError, RobotSpec, Step, check_action
from unilab_jax.robots.keys import ClientKeys


class _Channel:
    """One DEALER socket with request ids; replies to earlier (timed-out) requests are discarded."""

    def __init__(self, ctx: zmq.Context, address: str, client_id: str, keys: ClientKeys | None = None):
        self.address = address
        self.client_id = client_id
        self._ctx = ctx
        self._keys = keys
        self._ids = itertools.count(1)
        self._sock = None
        self._open()

    def _open(self) -> None:
        self._sock = self._ctx.socket(zmq.DEALER)
        self._sock.setsockopt(zmq.LINGER, 0)
        if self._keys is not None:
            self._sock.curve_serverkey = self._keys.server
            self._sock.curve_publickey, self._sock.curve_secretkey = self._keys.public, self._keys.secret
        self._sock.connect(self.address)

    def call(self, op: str, args: dict[str, Any] | None, timeout_s: float, token: str = "") -> Any:
        if timeout_s <= 0:  # nothing is sent that could still act after the caller gave up
            raise RobotDisconnected(f"robot server {self.address}: no time left to send {op!r}")
        req_id = next(self._ids)
        self._sock.send(protocol.request(op, req_id, self.client_id, args, token))
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not self._sock.poll(left * 1000, zmq.POLLIN):
                # A fresh socket: a late reply to this request must not be read as the next one's.
                self._sock.close(0)
                self._open()
                refused = " (or refused this client's key)" if self._keys is not None else ""
                raise RobotDisconnected(f"robot server {self.address} did not answer {op!r} within {timeout_s:.2f} s"
                                        f"{refused}")
            reply = protocol.unpack(self._sock.recv())
            if reply.get("id") != req_id:
                continue
            if not reply.get("ok"):
                protocol.raise_error(reply.get("error", {}))
            return reply.get("result")

    def close(self) -> None:
        self._sock.close(0)


def query(address: str, timeout_s: float = 1.0, keys: ClientKeys | None = None) -> tuple[RobotSpec, Health]:
    """A served robot's spec and health without claiming it (for inventories); RobotDisconnected if silent."""
    ctx = zmq.Context()
    chan = _Channel(ctx, address, f"query-{uuid.uuid4().hex[:12]}", keys)
    try:
        spec = RobotSpec.from_dict(chan.call("spec", None, timeout_s))
        health = chan.call("health", None, timeout_s)
    finally:
        chan.close()
        ctx.term()
    return spec, Health(**{f.name: health[f.name] for f in dataclasses.fields(Health)})


class RobotClient(Robot):
    """A Robot whose calls go to a robot server at ``address`` (``tcp://host:port``)."""

    def __init__(self, address: str, client_id: str | None = None, timeout_s: float = 2.0, lease_s: float = 5.0,
                 heartbeat_s: float | None = None, keys: ClientKeys | None = None):
        if timeout_s <= 0 or lease_s <= 0:
            raise ValueError(f"timeout_s and lease_s must be positive, got {timeout_s}, {lease_s}")
        self.address = address
        self.client_id = client_id or f"client-{uuid.uuid4().hex[:12]}"
        self.timeout_s = float(timeout_s)
        self.lease_s = float(lease_s)
        self.heartbeat_s = lease_s / 3 if heartbeat_s is None else float(heartbeat_s)
        self.keys = keys
        self._token = ""  # the claim's secret (robots.access)
        self._ctx: zmq.Context | None = None
        self._chan: _Channel | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None
        self._timeouts = 0
        self._disconnected = False
        self._last_health = Health("disconnected")
        self.spec: RobotSpec | None = None

    # ---------------------------------------------------------------------------------------------
    def connect(self) -> None:
        """Fetches the spec and claims the robot (raises RobotClaimed if another client holds it).

        Also the way back after RobotDisconnected or close(): e.g. once a restarted server is up."""
        if self._chan is None:
            self._ctx = zmq.Context()
            self._chan = _Channel(self._ctx, self.address, self.client_id, self.keys)
        self.spec = RobotSpec.from_dict(self._call("spec", None))
        self._token = self._call("claim", {"lease_s": self.lease_s})["token"]
        if self.heartbeat_s > 0 and self._beat is None:
            self._stop.clear()
            self._beat = threading.Thread(target=self._heartbeat_loop, name=f"heartbeat-{self.client_id}",
                                          daemon=True)
            self._beat.start()

    def reset(self, seed: int | None = None) -> dict[str, np.ndarray]:
        return self._call("reset", {"seed": seed}, extra_s=self._spec().reset_wall_s)

    def step(self, action: np.ndarray) -> Step:
        a = check_action(action).astype(np.float32)
        spec = self._spec()
        # A late step may also simulate up to max_hold_periods held periods (compute only).
        r = self._call("step", {"action": a}, extra_s=2 * spec.period_s)
        return Step(r["obs"], float(r["reward"]), bool(r["terminated"]), bool(r["truncated"]), r["info"])

    def estop(self) -> None:
        self._call("estop", None)

    def clear_estop(self) -> None:
        self._call("clear_estop", None)

    def heartbeat(self) -> Health:
        """Renews the claim; returns the server's health."""
        return self._health_from(self._call("heartbeat", None))

    def release(self) -> None:
        self._call("release", None)

    def health(self) -> Health:
        """The server's health; ``disconnected`` (with the last known counters) if it does not answer."""
        if self._chan is None:
            return self._last_health
        try:
            return self._health_from(self._call("health", None))
        except RobotDisconnected:
            return self._with_client_counts(self._last_health, "disconnected")

    def close(self) -> None:
        """Stops the heartbeat, releases the claim if the server answers, closes the socket."""
        self._stop.set()
        if self._beat is not None:
            self._beat.join(timeout=self.timeout_s + 1.0)
            self._beat = None
        if self._chan is not None:
            if not self._disconnected:
                try:
                    self._call("release", None, timeout_s=min(self.timeout_s, 0.5))
                except RobotError:
                    pass
            self._chan.close()
            self._chan = None
            self._ctx.term()
            self._ctx = None

    # ---------------------------------------------------------------------------------------------
    def _spec(self) -> RobotSpec:
        if self.spec is None:
            raise RobotError("call connect() first")
        return self.spec

    def _call(self, op: str, args: dict[str, Any] | None, extra_s: float = 0.0, timeout_s: float | None = None):
        """One request; the deadline covers waiting for a heartbeat in flight too, so a dead server is
        reported within ``timeout_s + extra_s`` of the call."""
        if self._chan is None:
            raise RobotError("call connect() first")
        budget = (timeout_s or self.timeout_s) + extra_s
        start = time.monotonic()
        if not self._lock.acquire(timeout=budget):
            self._timeouts += 1
            self._disconnected = True
            raise RobotDisconnected(f"robot server {self.address}: {op!r} could not be sent within {budget:.2f} s")
        try:
            result = self._chan.call(op, args, budget - (time.monotonic() - start), self._token)
        except RobotDisconnected:
            self._timeouts += 1
            self._disconnected = True
            raise
        except Exception:
            self._disconnected = False  # an error reply: the server is there
            raise
        finally:
            self._lock.release()
        self._disconnected = False
        return result

    def _health_from(self, d: dict[str, Any]) -> Health:
        self._last_health = Health(**{f.name: d[f.name] for f in dataclasses.fields(Health)})
        return self._with_client_counts(self._last_health, self._last_health.state)

    def _with_client_counts(self, h: Health, state: str) -> Health:
        return dataclasses.replace(h, state=state, dropped_messages=h.dropped_messages + self._timeouts)

    def _heartbeat_loop(self) -> None:
        while not self._stop.wait(self.heartbeat_s):
            try:
                self._call("heartbeat", None)
            except RobotError:
                continue
