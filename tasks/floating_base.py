"""Floating-base helpers on the shim: quaternions (``gravity_from_quat``, ``quat_mul``) and reset states of a
robot or object on a free joint (``place_base`` from given draws, ``random_base_states`` drawing them).

Written against the array-API shim on batched ``[M, ...]`` arrays, so the CPU tasks (numpy) and their MJX
variants (jax) share them; quaternions are (w, x, y, z), MuJoCo's order, and the free joint comes first in
``qpos`` / ``qvel``.
"""

from __future__ import annotations

import numpy as np

from unilab_jax import xp as shim


def gravity_from_quat(quat):
    """Gravity direction in the body frame, R(quat)^T @ (0, 0, -1); quat [M, 4] (w, x, y, z)."""
    xp = shim.namespace(quat)
    w, x, y, z = quat[:, 0], quat[:, 1], quat[:, 2], quat[:, 3]
    return -xp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)


def quat_mul(a, b):
    """Hamilton product of quaternions (w, x, y, z) over the leading axes (``[..., 4]``)."""
    xp = shim.namespace(a, b)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return xp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def place_base(init_qpos, dxy, yaw, base_vel, nv: int):
    """Reset states from draws: base xy ``init + dxy [n, 2]``, yaw ``yaw [n]`` composed with the initial
    orientation, base linear/angular velocity ``base_vel [n, 6]``, joint velocities 0 (free joint first)."""
    xp = shim.namespace(dxy, yaw, base_vel)
    n = yaw.shape[0]
    init = xp.broadcast_to(init_qpos, (n, init_qpos.shape[-1]))
    zeros = xp.zeros_like(yaw)
    qyaw = xp.stack([xp.cos(yaw / 2), zeros, zeros, xp.sin(yaw / 2)], axis=-1)
    qpos = xp.concat([init[:, 0:2] + dxy, init[:, 2:3], quat_mul(init[:, 3:7], qyaw), init[:, 7:]], axis=-1)
    qvel = xp.concat([base_vel, xp.zeros((n, nv - 6), dtype=base_vel.dtype)], axis=-1)
    return qpos, qvel


def random_base_states(init_qpos, nv: int, n: int, rng: np.random.Generator, xy: float, yaw: float,
                       base_vel: float) -> tuple[np.ndarray, np.ndarray]:
    """``n`` reset states around ``init_qpos`` (free joint first): base xy + U(+-xy), yaw U(+-yaw) composed
    with the initial orientation, base linear/angular velocity U(+-base_vel), joint velocities 0."""
    dxy = rng.uniform(-xy, xy, size=(n, 2))
    yaws = rng.uniform(-yaw, yaw, size=n)
    vel = rng.uniform(-base_vel, base_vel, size=(n, 6))
    return place_base(np.asarray(init_qpos, dtype=np.float64), dxy, yaws, vel, nv)
