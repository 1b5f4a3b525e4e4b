"""A policy-free algorithm module that acts on images (the image tests): uniform random actions, async replay.

``act`` takes ``image=`` (uint8 [M, H, W, C]) and writes the first 8 bytes of a BLAKE2b digest of each env's
image into the extra ``seen``, so a test can check that the policy acted on the image stored with its row."""

from __future__ import annotations

import hashlib

import numpy as np

SYNC = "async"
BUFFER = "replay"


def extras(action_dim: int) -> dict:
    return {"seen": ((8,), np.uint8)}


def digest(image: np.ndarray) -> np.ndarray:
    """uint8 [8]: the first bytes of BLAKE2b of one image."""
    return np.frombuffer(hashlib.blake2b(np.ascontiguousarray(image).tobytes(), digest_size=8).digest(), np.uint8)


def act(params: dict, obs: np.ndarray, noise: np.ndarray, deterministic: bool = False, image=None):
    if image is None or image.dtype != np.uint8 or image.shape[0] != obs.shape[0]:
        raise ValueError(f"act needs uint8 images [M, H, W, C], got {None if image is None else image.shape}")
    return np.tanh(noise).astype(np.float32), {"seen": np.stack([digest(im) for im in image])}
