"""``go1_joystick_flat``'s MDP as pure functions on the shim: observation, reward terms, termination, command
resampling and everything a control step computes after the physics.

The module-level functions work on batched arrays (``[M, ...]``, a feet axis of size 4 in ``FEET`` order)
written against the array-API shim (``xp = shim.namespace(...)``), so the CPU task (``tasks/go1_joystick.py``,
numpy) and its MJX variant (``tasks/mjx_go1.py``, jax) run this one MDP: ``read_sensors`` (named readings
from ``sensordata``), ``observe`` (actor 48 / critic 123 observations), the 16 Playground reward kernels and
``reward_terms``, ``step_math`` (a whole step after the physics, in Playground's order) and
``sample_command``. The walking tasks (``tasks/walking.py``) and ``g1_track`` reuse several kernels
(velocity tracking, base motion, action rate, torques, foot slip, joint limits) and ``scale_terms``.

The constants here define the MDP: ``FEET``, the reward terms and their default scales (``REWARD_SCALES``,
each a config field ``scale_<term>``), the observation sizes and the pose-term weights. The layouts and the
Playground parity choices are described in ``tasks/go1_joystick.py``'s docstring.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tasks.floating_base import gravity_from_quat
from unilab_jax import xp as shim

FEET = ("FR", "FL", "RR", "RL")
# Reward terms (in this order) and their default scales; each scale is the config field ``scale_<term>``.
REWARD_SCALES = {
    "tracking_lin_vel": 1.0, "tracking_ang_vel": 0.5, "lin_vel_z": -0.5, "ang_vel_xy": -0.05, "orientation": -5.0,
    "stand_still": -1.0, "termination": -1.0, "pose": 0.5, "torques": -0.0002, "action_rate": -0.01,
    "energy": -0.001, "feet_slip": -0.1, "feet_clearance": -2.0, "feet_height": -0.2, "feet_air_time": 0.1,
    "dof_pos_limits": -1.0,
}
REWARD_TERMS = tuple(REWARD_SCALES)
OBS_DIM = 48
CRITIC_OBS_DIM = OBS_DIM + 3 + 3 + 3 + 3 + 3 + 12 + 12 + 12 + 4 + 12 + 4 + 3 + 1  # 123
# Per-joint weights of the pose term (hip, thigh, calf for each leg).
POSE_WEIGHT = (1.0, 1.0, 0.1) * 4


def noise_scales(config: Any):
    """[33] per-entry noise amplitudes of the noisy actor inputs (linvel, gyro, gravity, qpos, qvel)."""
    c = config
    return np.concatenate(
        [
            np.full(3, c.noise_linvel),
            np.full(3, c.noise_gyro),
            np.full(3, c.noise_gravity),
            np.full(12, c.noise_joint_pos),
            np.full(12, c.noise_joint_vel),
        ]
    ) * c.noise_level


def actor_obs(local_linvel, gyro, gravity, joint_pos, joint_vel, last_act, command, default_pose, noise):
    """The 48-dim actor observation. ``noise [M, 33]`` = U(-1, 1) draws times ``noise_scales``."""
    xp = shim.namespace(local_linvel, gyro, gravity, joint_pos, joint_vel, last_act, command, noise)
    clean = xp.concat([local_linvel, gyro, gravity, joint_pos, joint_vel], axis=-1)
    noisy = clean + noise
    return xp.concat(
        [noisy[:, :9], noisy[:, 9:21] - default_pose, noisy[:, 21:33], last_act, command], axis=-1
    )


def critic_obs(actor, gyro, accelerometer, gravity, local_linvel, global_angvel, joint_pos, joint_vel,
               default_pose, actuator_force, last_contact, feet_vel, feet_air_time):
    """The 123-dim privileged observation (Playground's ``privileged_state``); feet_vel [M, 4, 3]."""
    xp = shim.namespace(actor, gyro, accelerometer, joint_pos, feet_vel)
    M = actor.shape[0]
    pert = xp.zeros((M, 4), dtype=actor.dtype)  # perturbation force (3) + active flag (1): disabled
    return xp.concat(
        [
            actor, gyro, accelerometer, gravity, local_linvel, global_angvel, joint_pos - default_pose,
            joint_vel, actuator_force, xp.astype(last_contact, actor.dtype),
            xp.reshape(feet_vel, (M, 12)), feet_air_time, pert,
        ],
        axis=-1,
    )


def feet_contact_update(contact, last_contact, air_time, swing_peak, feet_z, dt: float):
    """Playground's per-step foot bookkeeping, before the post-reward zeroing.

    Returns (first_contact [M, 4] bool, air_time + dt, max(swing_peak, feet_z)).
    """
    xp = shim.namespace(air_time, swing_peak, feet_z)
    contact_filt = contact | last_contact
    first_contact = (air_time > 0.0) & contact_filt
    return first_contact, air_time + dt, xp.maximum(swing_peak, feet_z)


def _norm(x, axis=-1):
    xp = shim.namespace(x)
    return xp.sqrt(xp.sum(xp.square(x), axis=axis))


def _f(mask, like):
    """bool -> float array of ``like``'s dtype."""
    return shim.namespace(like).astype(mask, like.dtype)


def reward_tracking_lin_vel(command, local_linvel, sigma: float):
    xp = shim.namespace(command, local_linvel)
    return xp.exp(-xp.sum(xp.square(command[:, :2] - local_linvel[:, :2]), axis=-1) / sigma)


def reward_tracking_ang_vel(command, gyro, sigma: float):
    xp = shim.namespace(command, gyro)
    return xp.exp(-xp.square(command[:, 2] - gyro[:, 2]) / sigma)


def cost_lin_vel_z(global_linvel):
    return shim.namespace(global_linvel).square(global_linvel[:, 2])


def cost_ang_vel_xy(global_angvel):
    xp = shim.namespace(global_angvel)
    return xp.sum(xp.square(global_angvel[:, :2]), axis=-1)


def cost_orientation(upvector):
    xp = shim.namespace(upvector)
    return xp.sum(xp.square(upvector[:, :2]), axis=-1)


def cost_stand_still(command, joint_pos, default_pose):
    xp = shim.namespace(command, joint_pos)
    still = _f(_norm(command) < 0.01, joint_pos)
    return xp.sum(xp.abs(joint_pos - default_pose), axis=-1) * still


def reward_pose(joint_pos, default_pose, weight):
    xp = shim.namespace(joint_pos)
    return xp.exp(-xp.sum(xp.square(joint_pos - default_pose) * weight, axis=-1))


def cost_torques(actuator_force):
    xp = shim.namespace(actuator_force)
    return _norm(actuator_force) + xp.sum(xp.abs(actuator_force), axis=-1)


def cost_action_rate(action, last_act):
    xp = shim.namespace(action, last_act)
    return xp.sum(xp.square(action - last_act), axis=-1)


def cost_energy(joint_vel, actuator_force):
    xp = shim.namespace(joint_vel, actuator_force)
    return xp.sum(xp.abs(joint_vel) * xp.abs(actuator_force), axis=-1)


def cost_feet_slip(command, feet_vel, contact):
    """feet_vel [M, 4, 3] (world), contact [M, 4] bool."""
    xp = shim.namespace(command, feet_vel)
    moving = _f(_norm(command) > 0.01, feet_vel)
    v2 = xp.sum(xp.square(feet_vel[..., :2]), axis=-1)
    return xp.sum(v2 * _f(contact, v2), axis=-1) * moving


def cost_feet_clearance(feet_vel, feet_z, max_foot_height: float):
    xp = shim.namespace(feet_vel, feet_z)
    vel_norm = xp.sqrt(_norm(feet_vel[..., :2]))
    return xp.sum(xp.abs(feet_z - max_foot_height) * vel_norm, axis=-1)


def cost_feet_height(command, swing_peak, first_contact, max_foot_height: float):
    xp = shim.namespace(command, swing_peak)
    moving = _f(_norm(command) > 0.01, swing_peak)
    err = swing_peak / max_foot_height - 1.0
    return xp.sum(xp.square(err) * _f(first_contact, err), axis=-1) * moving


def reward_feet_air_time(command, air_time, first_contact):
    xp = shim.namespace(command, air_time)
    moving = _f(_norm(command) > 0.01, air_time)
    return xp.sum((air_time - 0.1) * _f(first_contact, air_time), axis=-1) * moving


def cost_dof_pos_limits(joint_pos, soft_lower, soft_upper):
    xp = shim.namespace(joint_pos)
    zero = xp.zeros_like(joint_pos)
    out = -xp.minimum(joint_pos - soft_lower, zero) + xp.maximum(joint_pos - soft_upper, zero)
    return xp.sum(out, axis=-1)


def terminated(upvector):
    """[M] bool: the torso's up-vector points down."""
    return upvector[:, 2] < 0.0


def reward_terms(*, command, local_linvel, gyro, global_linvel, global_angvel, upvector, joint_pos,
                 joint_vel, default_pose, pose_weight, actuator_force, action, last_act, done, feet_vel,
                 feet_z, contact, first_contact, air_time, swing_peak, soft_lower, soft_upper,
                 tracking_sigma: float, max_foot_height: float):
    """Unscaled reward terms, each [M] (Playground's ``_get_reward``)."""
    return {
        "tracking_lin_vel": reward_tracking_lin_vel(command, local_linvel, tracking_sigma),
        "tracking_ang_vel": reward_tracking_ang_vel(command, gyro, tracking_sigma),
        "lin_vel_z": cost_lin_vel_z(global_linvel),
        "ang_vel_xy": cost_ang_vel_xy(global_angvel),
        "orientation": cost_orientation(upvector),
        "stand_still": cost_stand_still(command, joint_pos, default_pose),
        "termination": _f(done, joint_pos[:, 0]),
        "pose": reward_pose(joint_pos, default_pose, pose_weight),
        "torques": cost_torques(actuator_force),
        "action_rate": cost_action_rate(action, last_act),
        "energy": cost_energy(joint_vel, actuator_force),
        "feet_slip": cost_feet_slip(command, feet_vel, contact),
        "feet_clearance": cost_feet_clearance(feet_vel, feet_z, max_foot_height),
        "feet_height": cost_feet_height(command, swing_peak, first_contact, max_foot_height),
        "feet_air_time": reward_feet_air_time(command, air_time, first_contact),
        "dof_pos_limits": cost_dof_pos_limits(joint_pos, soft_lower, soft_upper),
    }


def scale_terms(terms, scales, dt: float):
    """{name: dt * scale * term} for every term."""
    return {k: terms[k] * (scales[k] * dt) for k in terms}


def total_reward(scaled_terms):
    """clip(sum of the scaled terms, 0, inf) [M]."""
    xp = shim.namespace(*scaled_terms.values())
    total = xp.sum(xp.stack(list(scaled_terms.values()), axis=0), axis=0)
    return xp.maximum(total, xp.zeros_like(total))


def sample_command(old, uniform, keep_nonzero, replace):
    """Playground's resampling: per axis, with ``replace`` swap in ``uniform * keep_nonzero``.

    old, uniform [M, 3] floats; keep_nonzero, replace [M, 3] bool.
    """
    xp = shim.namespace(old, uniform)
    new = uniform * xp.astype(keep_nonzero, uniform.dtype)
    return xp.where(replace, new, old)


def read_sensors(sensordata, index: dict[str, tuple[int, int]], nu: int) -> dict:
    """The named sensor readings the task math uses, from batched ``sensordata [M, nsensordata]``.

    ``feet_vel [M, 4, 3]`` and ``feet_z [M, 4]`` in FEET order, ``contact [M, 4]`` bool (the contact
    sensors' "found" count > 0), ``actuator_force [M, nu]``, ``gravity [M, 3]`` from the IMU quaternion.
    """
    xp = shim.namespace(sensordata)

    def get(name):
        adr, dim = index[name]
        return sensordata[:, adr : adr + dim]

    out = {k: get(k) for k in ("gyro", "local_linvel", "accelerometer", "upvector", "global_linvel",
                               "global_angvel", "orientation")}
    out["feet_vel"] = xp.stack([get(f"{f}_global_linvel") for f in FEET], axis=1)
    out["feet_z"] = xp.stack([get(f"{f}_pos")[:, 2] for f in FEET], axis=1)
    out["contact"] = xp.stack([get(f"{f}_floor_found")[:, 0] for f in FEET], axis=1) > 0
    adr0 = min(adr for name, (adr, _) in index.items() if name.endswith("_force"))
    out["actuator_force"] = sensordata[:, adr0 : adr0 + nu]
    out["gravity"] = gravity_from_quat(out["orientation"])
    return out


def observe(s, joint_pos, joint_vel, last_act, command, last_contact, air_time, default_pose, noise):
    """(actor obs [M, 48], critic obs [M, 123]) from sensor readings ``s`` (``read_sensors``) and task state."""
    obs = actor_obs(s["local_linvel"], s["gyro"], s["gravity"], joint_pos, joint_vel, last_act, command,
                    default_pose, noise)
    cobs = critic_obs(obs, s["gyro"], s["accelerometer"], s["gravity"], s["local_linvel"], s["global_angvel"],
                      joint_pos, joint_vel, default_pose, s["actuator_force"], last_contact, s["feet_vel"], air_time)
    return obs, cobs


def step_math(s, joint_pos, joint_vel, action, info, noise, consts, config: Any, scales, dt: float):
    """Everything a control step computes after the physics, in Playground's order; shared by the CPU
    task and the MJX variant (``tasks/mjx_go1.py``), so both are one MDP.

    ``info``: the per-env episode state before the step (``command``, ``last_act``, ``feet_air_time``,
    ``last_contact``, ``swing_peak``); ``consts``: ``default_pose``, ``pose_weight``, ``soft_lower``,
    ``soft_upper``; ``noise [M, 33]`` the observation noise already scaled. Returns (next_obs, next_cobs,
    done [M] bool, scaled terms, reward [M], the updated foot/action entries of ``info``). Command
    resampling is left to the caller (it draws random numbers conditionally).
    """
    contact = s["contact"]
    first_contact, air_time, swing_peak = feet_contact_update(
        contact, info["last_contact"], info["feet_air_time"], info["swing_peak"], s["feet_z"], dt
    )
    next_obs, next_cobs = observe(s, joint_pos, joint_vel, info["last_act"], info["command"], info["last_contact"],
                                  air_time, consts["default_pose"], noise)
    done = terminated(s["upvector"])
    terms = reward_terms(
        command=info["command"], local_linvel=s["local_linvel"], gyro=s["gyro"], global_linvel=s["global_linvel"],
        global_angvel=s["global_angvel"], upvector=s["upvector"], joint_pos=joint_pos, joint_vel=joint_vel,
        default_pose=consts["default_pose"], pose_weight=consts["pose_weight"], actuator_force=s["actuator_force"],
        action=action, last_act=info["last_act"], done=done, feet_vel=s["feet_vel"], feet_z=s["feet_z"],
        contact=contact, first_contact=first_contact, air_time=air_time, swing_peak=swing_peak,
        soft_lower=consts["soft_lower"], soft_upper=consts["soft_upper"], tracking_sigma=config.tracking_sigma,
        max_foot_height=config.max_foot_height,
    )
    scaled = scale_terms(terms, scales, dt)
    reward = total_reward(scaled)
    # Bookkeeping after the reward (Playground's order).
    updated = {"last_act": action, "feet_air_time": air_time * ~contact, "last_contact": contact,
               "swing_peak": swing_peak * ~contact}
    return next_obs, next_cobs, done, scaled, reward, updated
