"""Teleoperation input: one ``TeleopDevice`` protocol for whatever drives a robot during demonstrations.

A device maps the robot's observation dict (``robots.interface``) to the 7-D end-effector action
(``interface.ACTION_LAYOUT``: position delta, rotation delta, gripper), one call per control step::

    device.reset()                 # at each episode start
    action = device(obs)           # float32 [7] in [-1, 1]
    device.close()

Implementations here:

* ``ExpertDevice``: the scripted expert of the robot's task (``robots.experts``; reads ``obs["privileged"]``).
* ``KeyboardDevice``: keys read from a byte stream (a terminal in raw mode, or any pipe): each key pressed
  since the last step adds a unit command on its axis for that step; the gripper toggles on a space.
  Keys: ``w/s`` +x/-x, ``a/d`` +y/-y, ``r/f`` +z/-z, ``q/e`` +yaw/-yaw, space: gripper.

A SpaceMouse needs its HID driver and the device; ``make_device("spacemouse", ...)`` says so
(``SpaceMouseUnavailable``) instead of recording without it.
"""

from __future__ import annotations

import os
import select
from typing import Protocol, runtime_checkable

import numpy as np

from unilab_jax.robots.interface import ACTION_DIM, RobotSpec

DEVICES = ("expert", "keyboard", "spacemouse")
# key -> (action index, sign)
KEYMAP = {b"w": (0, 1.0), b"s": (0, -1.0), b"a": (1, 1.0), b"d": (1, -1.0), b"r": (2, 1.0), b"f": (2, -1.0),
          b"q": (5, 1.0), b"e": (5, -1.0)}
GRIPPER_KEY = b" "


@runtime_checkable
class TeleopDevice(Protocol):
    """What drives a robot while demonstrations are recorded (see the module docstring)."""

    def reset(self) -> None: ...

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray: ...

    def close(self) -> None: ...


class SpaceMouseUnavailable(RuntimeError):
    """A SpaceMouse was asked for; this installation has no driver for it."""


class ExpertDevice:
    """The scripted expert of ``spec.task`` as a teleoperation device."""

    def __init__(self, spec: RobotSpec):
        from unilab_jax.robots.experts import make_expert

        self.expert = make_expert(spec)

    def reset(self) -> None:
        self.expert.reset()

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.asarray(self.expert(obs), np.float32)

    def close(self) -> None:
        pass


class KeyboardDevice:
    """Keys from the file descriptor ``fd`` (default: the terminal, switched to raw mode until ``close``).

    Each call reads every byte available without blocking; unknown keys are ignored.
    """

    def __init__(self, fd: int | None = None):
        self._restore = None
        if fd is None:
            import termios
            import tty

            fd = os.open("/dev/tty", os.O_RDONLY)
            saved = termios.tcgetattr(fd)
            tty.setcbreak(fd)
            self._restore = lambda: (termios.tcsetattr(fd, termios.TCSADRAIN, saved), os.close(fd))
        self.fd = fd
        self.grip = -1.0

    def reset(self) -> None:
        self.grip = -1.0

    def _pending(self) -> bytes:
        data = b""
        while select.select([self.fd], [], [], 0.0)[0]:
            chunk = os.read(self.fd, 256)
            if not chunk:
                break
            data += chunk
        return data

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        action = np.zeros(ACTION_DIM, np.float32)
        for key in self._pending().lower():
            k = bytes([key])
            if k == GRIPPER_KEY:
                self.grip = -self.grip
            elif k in KEYMAP:
                axis, sign = KEYMAP[k]
                action[axis] += sign
        action[6] = self.grip
        return np.clip(action, -1.0, 1.0)

    def close(self) -> None:
        if self._restore is not None:
            self._restore()
            self._restore = None


def make_device(name: str, spec: RobotSpec) -> TeleopDevice:
    """The device ``name`` (one of ``DEVICES``) for robots of ``spec``."""
    if name == "expert":
        return ExpertDevice(spec)
    if name == "keyboard":
        return KeyboardDevice()
    if name == "spacemouse":
        raise SpaceMouseUnavailable("--device=spacemouse: no SpaceMouse driver in this installation (it needs the "
                                    "device, hidapi and a HID driver); record with --device=expert or keyboard")
    raise ValueError(f"unknown teleoperation device {name!r}; choose one of {DEVICES}")
