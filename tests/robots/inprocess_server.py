"""A robot server in a thread of the test process (a simulated Franka, no cameras), for the server tests."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

from unilab_jax.robots.server import RobotServer, ServerConfig
from unilab_jax.robots.sim import SimConfig, SimRobot


@contextlib.contextmanager
def thread_server(speed: float = 20.0, reset_seconds: float = 0.1, **server_kw) -> Iterator[RobotServer]:
    """A server on a free port serving until the block ends (``server_kw``: ``ServerConfig``'s fields)."""
    robot = SimRobot(SimConfig(cameras=(), speed=speed, reset_seconds=reset_seconds))
    server = RobotServer(robot, ServerConfig(**server_kw))
    stop = threading.Event()
    thread = threading.Thread(target=server.serve, args=(stop,), daemon=True)
    thread.start()
    try:
        yield server
    finally:
        stop.set()
        thread.join(10)
        assert not thread.is_alive()
