"""End-effector control: damped-least-squares differential IK and the rotation helpers it needs.

Quaternions are ``(w, x, y, z)`` float64 ``[4]``; rotation vectors (axis-angle) are ``[3]`` radians.
"""

from __future__ import annotations

import mujoco
import numpy as np


def quat_from_rotvec(v: np.ndarray) -> np.ndarray:
    """Rotation vector [3] -> unit quaternion [4]."""
    v = np.asarray(v, dtype=np.float64)
    angle = float(np.linalg.norm(v))
    q = np.zeros(4)
    if angle < 1e-12:
        q[0] = 1.0
        return q
    mujoco.mju_axisAngle2Quat(q, v / angle, angle)
    return q


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of quaternions [4]."""
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return out


def quat_error(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """World-frame rotation vector [3] that turns ``current`` into ``target`` (both quaternions [4])."""
    conj = np.asarray(current, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])
    d = quat_mul(target, conj)
    if d[0] < 0:
        d = -d
    s = float(np.linalg.norm(d[1:]))
    if s < 1e-12:
        return np.zeros(3)
    return d[1:] / s * 2.0 * np.arctan2(s, d[0])


def mat_to_quat(mat: np.ndarray) -> np.ndarray:
    """Rotation matrix [9] or [3, 3] -> unit quaternion [4]."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(mat, dtype=np.float64).reshape(9))
    return q


def yaw_of_quat(q: np.ndarray) -> float:
    """Rotation angle about world z of the body x axis (radians)."""
    w, x, y, z = q
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def site_pose_error(model: mujoco.MjModel, data: mujoco.MjData, site: int, pos: np.ndarray,
                    quat: np.ndarray) -> np.ndarray:
    """[6] (position error, rotation-vector error) from site ``site``'s current pose to (pos [3], quat [4])."""
    err = np.empty(6)
    err[:3] = pos - data.site_xpos[site]
    err[3:] = quat_error(quat, mat_to_quat(data.site_xmat[site]))
    return err


def dls_step(jac: np.ndarray, err: np.ndarray, damping: float) -> np.ndarray:
    """Damped least squares: dq [n] = J^T (J J^T + damping^2 I)^-1 err, for J [6, n], err [6]."""
    jjt = jac @ jac.T
    return jac.T @ np.linalg.solve(jjt + damping**2 * np.eye(jac.shape[0]), err)


def solve_ik(model: mujoco.MjModel, scratch: mujoco.MjData, site: int, qpos_adr: np.ndarray, dof_adr: np.ndarray,
             q_limits: np.ndarray, pos: np.ndarray, quat: np.ndarray, iterations: int = 3,
             damping: float = 0.05, max_step: float = 0.3) -> np.ndarray:
    """Arm joint positions [n] that bring ``site`` towards (pos [3], quat [4]).

    ``scratch`` holds the starting configuration in ``qpos`` and is overwritten (kinematics only);
    ``q_limits`` [n, 2] clamps the result; each iteration's joint change is capped at ``max_step`` rad.
    """
    jacp = np.zeros((3, model.nv))
    jacr = np.zeros((3, model.nv))
    q = scratch.qpos[qpos_adr].copy()
    for _ in range(iterations):
        mujoco.mj_kinematics(model, scratch)
        mujoco.mj_comPos(model, scratch)
        err = site_pose_error(model, scratch, site, pos, quat)
        mujoco.mj_jacSite(model, scratch, jacp, jacr, site)
        jac = np.vstack([jacp[:, dof_adr], jacr[:, dof_adr]])
        dq = dls_step(jac, err, damping)
        peak = float(np.max(np.abs(dq)))
        if peak > max_step:
            dq *= max_step / peak
        q = np.clip(q + dq, q_limits[:, 0], q_limits[:, 1])
        scratch.qpos[qpos_adr] = q
    return q
