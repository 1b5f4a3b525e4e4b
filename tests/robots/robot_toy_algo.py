"""A policy-free algorithm module for the robot runtime tests: uniform random actions, async replay."""

from __future__ import annotations

import numpy as np

SYNC = "async"
BUFFER = "replay"


def extras(action_dim: int) -> dict:
    return {}


def act(params: dict, obs: np.ndarray, noise: np.ndarray, deterministic: bool = False):
    return np.tanh(noise).astype(np.float32), {}
