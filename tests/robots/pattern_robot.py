"""A simulated robot whose camera frames are a known function of its proprioception (the image tests).

``PatternRobot`` is a ``SimRobot`` (peg insertion, unpaced, no rendering) whose observations also hold one
``[S, S, 3]`` uint8 frame per camera: :func:`frame` of the observation's ``proprio`` bytes and the camera's
name, so a test can recompute, from any observation it sees, the exact bytes the robot sent with it.
``serving(n)`` serves ``n`` of them from threads of this process."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import threading

import numpy as np

from unilab_jax.robots.interface import Robot, Step
from unilab_jax.robots.server import RobotServer, ServerConfig
from unilab_jax.robots.sim import SimConfig, SimRobot

PROPRIO = 13


def frame(proprio: np.ndarray, camera: str, size: int) -> np.ndarray:
    """uint8 [size, size, 3]: BLAKE2b of the proprio bytes and the camera name, repeated to fill the frame."""
    seed = hashlib.blake2b(np.asarray(proprio, np.float32).tobytes() + camera.encode(), digest_size=64).digest()
    n = size * size * 3
    return np.frombuffer((seed * (n // 64 + 1))[:n], np.uint8).reshape(size, size, 3)


class PatternRobot(Robot):
    def __init__(self, seed: int = 0, cameras: tuple[str, ...] = ("front", "wrist"), size: int = 16):
        self.sim = SimRobot(SimConfig(task="peg_insertion", cameras=(), speed=float("inf"), reset_seconds=0.0,
                                      seed=seed))
        self.cameras, self.size = cameras, size
        self.spec = dataclasses.replace(self.sim.spec, cameras=cameras, image_shape=(size, size, 3))

    def _with_frames(self, obs: dict) -> dict:
        return {**obs, **{c: frame(obs["proprio"], c, self.size) for c in self.cameras}}

    def reset(self, seed: int | None = None) -> dict:
        return self._with_frames(self.sim.reset(seed))

    def step(self, action: np.ndarray) -> Step:
        s = self.sim.step(action)
        return s._replace(obs=self._with_frames(s.obs))

    def estop(self) -> None:
        self.sim.estop()

    def clear_estop(self) -> None:
        self.sim.clear_estop()

    def health(self):
        return self.sim.health()


@contextlib.contextmanager
def serving(n: int, **robot_kw):
    """Addresses of ``n`` robot servers of pattern robots (seeds 0..n-1), served from threads until the exit."""
    stop = threading.Event()
    servers = [RobotServer(PatternRobot(seed=i, **robot_kw), ServerConfig()) for i in range(n)]
    threads = [threading.Thread(target=s.serve, args=(stop,), daemon=True) for s in servers]
    for t in threads:
        t.start()
    try:
        yield [s.address for s in servers]
    finally:
        stop.set()
        for t in threads:
            t.join(10)
