"""Curricula of the rough-terrain tasks as pure functions on the array-API shim (numpy in the CPU workers, jax in
the MJX variants): legged_gym's terrain curriculum and its command curriculum (Rudin et al. 2021).

Randomness comes in as arrays (the shim's convention: the caller draws it), so every rule here is
deterministic and tested by hand.

* ``initial_cells``: the starting (level, column) of each env: columns in equal consecutive blocks of envs,
  levels from the given draws in ``[0, max_init_level]`` (legged_gym).
* ``next_levels``: the "game-inspired" rule applied to envs at reset: a robot that walked farther than half a
  cell moves one level up; one that walked less than half of the distance its command asked for over the
  episode moves one level down (never below 0); one promoted past the top level goes to a random level.
* ``advance_commanded_path`` and ``asked_distance``: what the command asked for: the distance from its start that
  a robot following its commands exactly would reach, the body-frame planar velocity integrated along the heading
  the commanded yaw rate turns, scaled from the steps the episode lasted to the full time limit (a robot that
  fell early is measured against a whole episode, as in legged_gym). legged_gym's ``|cmd_xy| * episode_length_s``
  is the path's length, not its reach: with commands resampled every ~5 s and yaw rates up to 1.2 rad/s (the
  Go1 task's), a robot making 80% of the commanded displacement was demoted after 54% of its episodes and
  promoted after 46% (a drift down; docs/TERRAIN.md), so the curriculum held every imperfect walker on level 0.
* ``advance_walked_path`` (the ``path`` measure, ``RoughConfig.curriculum_distance``): the distance a robot made
  along its commanded direction and the commanded path's length, for tasks whose command holds one yaw rate for a
  whole episode (the Go2 and G1 walking tasks: ``U(-0.8, 0.8)`` rad/s): their commanded paths are circles, whose
  reach after 20 s exceeds half a cell (4 m) for 23% of the commands (a perfect tracker), so under the displacement
  rule a walker sinks to level 0 (two Go2 runs: no robot ever promoted); their path length exceeds it for 90%.
  The distance is the base's planar velocity projected on the commanded direction, integrated: signed, so a robot
  that rocks in place makes none and one that backs away against its command makes less than none.
* ``widen_commands``: the command curriculum: when the tracking reward of the episodes that ended reached
  ``threshold`` of its maximum, every command range grows by ``step`` (per axis) up to its final range.
"""

from __future__ import annotations

from unilab_jax import xp as shim


def initial_cells(num_envs: int, columns: int, level_draws):
    """(levels [M], columns [M]) of the envs' first cells: env i in column ``floor(i * columns / num_envs)``
    (equal consecutive blocks), level ``level_draws [M]`` (ints in [0, max_init_level], drawn by the caller)."""
    xp = shim.namespace(level_draws)
    cols = xp.astype(xp.floor(xp.arange(num_envs) * (columns / num_envs)), level_draws.dtype)
    return level_draws, cols


def next_levels(levels, distance, asked, cell_size: float, num_levels: int, random_levels):
    """Terrain levels after an episode (legged_gym's ``_update_terrain_curriculum``), each [n]: ``distance`` walked
    from the cell's origin, ``asked`` the distance the command asked for over the episode (``asked_distance``),
    ``random_levels`` ints in [0, num_levels) for robots promoted past the top."""
    xp = shim.namespace(levels, distance, asked)
    up = distance > cell_size / 2
    down = (distance < asked / 2) & ~up
    new = levels + xp.astype(up, levels.dtype) - xp.astype(down, levels.dtype)
    return xp.where(new >= num_levels, random_levels, xp.maximum(new, xp.zeros_like(new)))


def advance_commanded_path(displacement, heading, command, dt: float):
    """One control step of the commanded path: ``displacement [n, 2]``, where a robot that followed its commands
    exactly would be relative to its start (in the frame of its initial heading), and ``heading [n]``, its heading
    relative to the initial one, after ``dt`` seconds of ``command [n, 3]`` (body-frame vx, vy, yaw rate).
    Returns the new (displacement, heading)."""
    xp = shim.namespace(displacement, heading, command)
    c, s = xp.cos(heading), xp.sin(heading)
    vx, vy = command[:, 0], command[:, 1]
    step = xp.stack([c * vx - s * vy, s * vx + c * vy], axis=1)
    return displacement + dt * step, heading + dt * command[:, 2]


def per_episode(total, steps, episode_length: int):
    """[n] ``total [n]``, accumulated over ``steps [n]`` control steps, scaled to the full ``episode_length`` (a robot
    that fell early is measured against a whole episode); 0 for an empty episode."""
    xp = shim.namespace(total, steps)
    return total * episode_length / xp.maximum(xp.astype(steps, total.dtype), xp.ones_like(total))


def asked_distance(displacement, steps, episode_length: int):
    """[n] the distance the commands asked for: the reach of the commanded path after ``steps`` (``displacement
    [n, 2]`` from ``advance_commanded_path``) scaled to the full ``episode_length`` (0 for an empty episode)."""
    xp = shim.namespace(displacement, steps)
    return per_episode(xp.sqrt(xp.sum(displacement * displacement, axis=1)), steps, episode_length)


def advance_walked_path(walked, asked, velocity, yaw, command, dt: float):
    """One control step of the ``path`` measure: ``walked [n]`` plus the base's world-frame planar ``velocity
    [n, 2]`` projected on the command's direction (the body-frame ``command [n, 3]``'s (vx, vy) turned by the base
    ``yaw [n]``) times ``dt``, and ``asked [n]`` plus the commanded planar speed times ``dt`` (the commanded path's
    length). A zero planar command adds nothing to either. Returns (walked, asked)."""
    xp = shim.namespace(walked, velocity, command)
    vx, vy = command[:, 0], command[:, 1]
    speed = xp.sqrt(vx * vx + vy * vy)
    c, s = xp.cos(yaw), xp.sin(yaw)
    along = (velocity[:, 0] * (c * vx - s * vy) + velocity[:, 1] * (s * vx + c * vy)) / xp.maximum(
        speed, xp.full_like(speed, 1e-9))
    return walked + dt * along, asked + dt * speed


def widen_commands(current, final, step, tracking, threshold: float = 0.8):
    """The command ranges after an update of the command curriculum: ``current + step`` capped at ``final``
    (per axis, arrays of equal shape) when ``tracking`` (the ended episodes' mean tracking reward per step
    over the full episode, in [0, 1] of its maximum) is at least ``threshold``; else unchanged."""
    xp = shim.namespace(current)
    return xp.where(tracking >= threshold, xp.minimum(current + step, final), current)
