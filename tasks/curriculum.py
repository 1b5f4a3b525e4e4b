"""Curricula of the rough-terrain tasks as pure functions on the array-API shim (numpy in the CPU workers, jax in
the MJX variants): legged_gym's terrain curriculum and its command curriculum (Rudin et al. 2021).

Randomness comes in as arrays (the shim's convention: the caller draws it), so every rule here is
deterministic and tested by hand.

* ``initial_cells``: the starting (level, column) of each env: columns in equal consecutive blocks of envs,
  levels from the given draws in ``[0, max_init_level]`` (legged_gym).
* ``next_levels``: the "game-inspired" rule applied to envs at reset: a robot that walked farther than half a
  cell moves one level up; one that walked less than half of the distance its command asked for over the
  episode moves one level down (never below 0); one promoted past the top level goes to a random level.
* ``asked_distance``: what the command asked for, legged_gym's ``|cmd_xy| * episode_length_s``, with the
  command's mean speed over the steps the episode lasted (commands are resampled during an episode) and the
  full time limit, so a robot that fell early is measured against a whole episode (legged_gym's effect).
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


def asked_distance(speed_sum, steps, episode_seconds: float):
    """[n] the distance a command asked for: the mean commanded planar speed over the episode's ``steps``
    (``speed_sum`` the sum of |cmd_xy| over them) times the full episode duration (0 for an empty episode)."""
    xp = shim.namespace(speed_sum, steps)
    mean = speed_sum / xp.maximum(xp.astype(steps, speed_sum.dtype), xp.ones_like(speed_sum))
    return mean * episode_seconds


def widen_commands(current, final, step, tracking, threshold: float = 0.8):
    """The command ranges after an update of the command curriculum: ``current + step`` capped at ``final``
    (per axis, arrays of equal shape) when ``tracking`` (the ended episodes' mean tracking reward per step
    over the full episode, in [0, 1] of its maximum) is at least ``threshold``; else unchanged."""
    xp = shim.namespace(current)
    return xp.where(tracking >= threshold, xp.minimum(current + step, final), current)
