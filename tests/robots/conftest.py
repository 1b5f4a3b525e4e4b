"""Fixtures for the robot tests: robot-server subprocesses (always stopped) and the GL backend probe."""

from __future__ import annotations

import contextlib
import os
import queue
import subprocess
import sys
import threading
import time

import pytest

from unilab_jax.robots.client import RobotClient
from unilab_jax.robots.gl import find_gl_backend

START_TIMEOUT_S = 60.0


class ServerProcess:
    """A ``python -m unilab_jax.robots.serve`` subprocess; ``address`` is read from its first line."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None):
        cmd = [sys.executable, "-m", "unilab_jax.robots.serve", *args]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env={**os.environ, **(env or {})})
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: lines.put(self.proc.stdout.readline()), daemon=True).start()
        try:
            line = lines.get(timeout=START_TIMEOUT_S)
        except queue.Empty:
            self.stop()
            raise RuntimeError(f"robot server {args} did not start within {START_TIMEOUT_S} s") from None
        if not line.startswith("serving "):
            self.stop(read_stderr=True)
            raise RuntimeError(f"robot server {args} failed: {line!r} {self.stderr_tail}")
        self.address = line.split(" on ")[1].strip()
        self.port = int(self.address.rsplit(":", 1)[1])

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait(10)

    def stop(self, read_stderr: bool = False) -> int:
        """SIGTERM, then SIGKILL after 5 s; returns the exit status (``read_stderr``: keep its tail)."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.kill()
        if read_stderr:
            self.stderr_tail = self.proc.stderr.read()[-2000:]
        for stream in (self.proc.stdout, self.proc.stderr):
            stream.close()
        return self.proc.returncode


@pytest.fixture
def serve():
    """``serve(*args, env=None) -> ServerProcess``; every server started is stopped at teardown."""
    started: list[ServerProcess] = []

    def start(*args: str, env: dict[str, str] | None = None) -> ServerProcess:
        server = ServerProcess(list(args), env)
        started.append(server)
        return server

    yield start
    for server in started:
        with contextlib.suppress(Exception):
            server.stop()


@pytest.fixture
def client():
    """``client(address, **kw) -> RobotClient`` (not connected); every one is closed at teardown, so a
    failing test leaves no heartbeat thread or socket behind."""
    made: list[RobotClient] = []

    def make(address: str, **kw) -> RobotClient:
        made.append(RobotClient(address, **kw))
        return made[-1]

    yield make
    for c in made:
        with contextlib.suppress(Exception):
            c.close()


@pytest.fixture(scope="session")
def gl_backend() -> str:
    """A MUJOCO_GL value that renders here; skips (with each backend's failure) if there is none."""
    t = time.perf_counter()
    backend, reasons = find_gl_backend()
    if backend is None:
        pytest.skip(f"no offscreen GL backend could be created ({time.perf_counter() - t:.1f} s): {reasons}")
    return backend
