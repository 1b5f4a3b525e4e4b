"""Grasp cache of ``allegro_rotate`` (HORA's start: stable grasps sampled in advance, an episode starts from one).

A grasp is a simulated state in which the fingers hold the object: hand joints and object pose (``qpos [23]``),
the position targets that hold it (``target [16]``) and the object it holds (shape, size scale, mass, friction,
centre-of-mass offset); ``tasks/allegro_grasp_sampler.py`` makes them (``python -m tasks.allegro_grasp_sampler``).
A cache file (``.npz``) records the physics it was made with (``PHYSICS_FIELDS`` of the task config);
``load`` refuses a config whose physics differ, and keeps the grasps of ``config.shapes`` (grouped by shape).
``"builtin"`` is ``tasks/data/allegro_grasps.npz``, made for the default physics by
``python -m tasks.allegro_grasp_sampler --out tasks/data/allegro_grasps.npz --candidates 12288`` (841 grasps:
417 cylinders, 424 boxes); ``"held"`` is ``tasks/data/allegro_grasps_held.npz``, its 733 grasps (366 cylinders, 367
boxes) that keep their object for a whole still episode (``python -m tasks.allegro_grasp_sampler --from
tasks/data/allegro_grasps.npz --hold_steps 400 --out tasks/data/allegro_grasps_held.npz``: 13% of the builtin
cache's starts lose the object with no action at all, 1% of these). ``draw`` (shim-written) picks grasps for the
CPU task and ``tasks/mjx_allegro.py`` alike: a shape uniform over ``config.shapes``, then one of its grasps
uniformly. The object of an episode is the grasp's (its size, mass, friction and centre of mass were drawn from
the task's ranges, then kept only if held: a selected distribution, not the uniform one).

Measured with the builtin cache (64 envs, zero actions, so the targets stay the grasp's): at reset every object
is touched by >= 2 fingers (52 by 2, 12 by 3); after 5 s 46 still by >= 2; time to fall 0.89 over the 400 steps
(the palm start: 1.0, with no finger touching).
"""

from __future__ import annotations

import dataclasses
import json
import os
from typing import Any

import numpy as np

from unilab_jax import xp as shim

BUILTIN = os.path.join(os.path.dirname(__file__), "data", "allegro_grasps.npz")
NAMED = {"builtin": BUILTIN, "held": os.path.join(os.path.dirname(__file__), "data", "allegro_grasps_held.npz")}
PHYSICS_FIELDS = ("ctrl_dt", "sim_dt", "kp", "kd", "torque_limit", "solver_iterations", "ls_iterations",
                  "integrator", "fall_radius", "domain_randomization", "dr_scale", "dr_mass", "dr_com_offset",
                  "dr_friction")
FIELDS = ("qpos", "target", "shape", "scale", "mass", "friction", "com")


def physics(config) -> dict:
    """The config fields a grasp depends on, as JSON values."""
    return json.loads(json.dumps({k: getattr(config, k) for k in PHYSICS_FIELDS}))


def path_of(name: str) -> str:
    """The file of a cache name: a named cache (``NAMED``) or a path."""
    return NAMED.get(name, name)


def load(config) -> dict[str, np.ndarray]:
    """The grasps of ``config.grasp_cache`` for ``config.shapes``, grouped by shape: ``FIELDS`` (``shape``:
    index into ``config.shapes``) plus ``start`` and ``count`` [G] (each shape's rows). ValueError: no file,
    other physics, or a shape without grasps."""
    made, names, data = _contents(config.grasp_cache)
    want = physics(config)
    diff = sorted(k for k in want if made.get(k) != want[k])
    if diff:
        raise ValueError(f"grasp_cache {config.grasp_cache!r} was made with other physics ({', '.join(diff)}: "
                         f"{[made.get(k) for k in diff]} vs {[want[k] for k in diff]}); make one with python -m "
                         f"tasks.allegro_grasp_sampler --out FILE --task_config ...")
    rows, count = [], []
    for s in config.shapes:
        r = np.flatnonzero(data["shape"] == names.index(s)) if s in names else np.zeros(0, np.int64)
        if r.size == 0:
            raise ValueError(f"grasp_cache {config.grasp_cache!r} holds no {s} grasp")
        rows.append(r)
        count.append(r.size)
    order = np.concatenate(rows)
    out = {k: data[k][order] for k in FIELDS}
    out["shape"] = np.repeat(np.arange(len(config.shapes)), count)
    out["count"] = np.array(count)
    out["start"] = np.cumsum(out["count"]) - out["count"]
    return out


def read(path: str, config) -> tuple[Any, dict[str, np.ndarray]]:
    """(``config`` with the file's physics and shapes, the file's grasps: ``FIELDS``, ``shape`` indexing those
    shapes) of the cache ``path`` (or a named one: ``NAMED``), as made; ValueError: no such file."""
    made, shapes, grasps = _contents(path)
    made = {k: tuple(v) if isinstance(v, list) else v for k, v in made.items()}
    return dataclasses.replace(config, shapes=tuple(shapes), **made), grasps


def _contents(name: str) -> tuple[dict, list[str], dict[str, np.ndarray]]:
    """(the physics it was made with, its shapes, its ``FIELDS``) of the cache file ``name`` (``path_of``)."""
    path = path_of(name)
    if not os.path.isfile(path):
        raise ValueError(f"grasp_cache {name!r}: no such file (make one with python -m "
                         f"tasks.allegro_grasp_sampler --out FILE)")
    with np.load(path) as f:
        return json.loads(str(f["physics"])), [str(s) for s in f["shapes"]], {k: f[k] for k in FIELDS}


def draw(grasps: dict, shape, u) -> dict:
    """The grasps picked by ``shape [n]`` (index into the cache's shapes) and ``u [n]`` in [0, 1): the
    ``shape``'s ``floor(u * count)``-th grasp. Returns the task's object draws (``active [n, G]`` one-hot,
    ``scale``, ``mass``, ``friction`` [n], ``com [n, 3]``) and ``qpos [n, 23]``, ``target [n, 16]``.
    Shim-written: ``grasps`` (arrays of ``load``) and the draws of one backend."""
    xp = shim.namespace(u)
    count = grasps["count"][shape]
    k = grasps["start"][shape] + xp.minimum(xp.astype(xp.floor(u * count), count.dtype), count - 1)
    active = xp.one_hot(shape, len(grasps["count"]), dtype=grasps["scale"].dtype)
    return {"active": active, **{name: grasps[name][k] for name in FIELDS if name != "shape"}}


def save(path: str, grasps: dict, config) -> None:
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    np.savez_compressed(path, physics=json.dumps(physics(config)), shapes=np.array(config.shapes), **grasps)
