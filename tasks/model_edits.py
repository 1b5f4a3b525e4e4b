"""Task models: Menagerie robots as editable ``mujoco.MjSpec`` objects, the MjSpec edits the tasks share, and
the sensor layout of a compiled model.

The Menagerie tasks (Go1, Go2, G1, Allegro) build their models from Menagerie's files with MjSpec edits
(never a copied XML): ``load_menagerie_spec`` (``MENAGERIE_ROOT`` for offline copies), ``set_solver``
(timestep, integrator, Newton iterations, pyramidal cone), ``strip_visuals`` (meshes, textures and
materials, which have no effect on physics and would make per-env model copies large) and, for the legged
robots, ``feet_only_contacts``. ``sensor_index`` maps sensor names to their slice of ``sensordata``, which
MuJoCo and MJX lay out alike.
"""

from __future__ import annotations

import os

import mujoco


def load_menagerie_spec(robot: str, variant: str = "scene") -> mujoco.MjSpec:
    """A Menagerie robot's ``variant`` XML as an editable MjSpec (``MENAGERIE_ROOT`` for offline copies)."""
    import mujoco_menagerie

    root = os.environ.get("MENAGERIE_ROOT")
    if root and not os.path.isdir(root):
        raise FileNotFoundError(f"MENAGERIE_ROOT={root!r} is not a directory")
    return mujoco_menagerie.get(robot).spec(variant)


def set_solver(spec: mujoco.MjSpec, config) -> None:
    """Timestep ``config.sim_dt``, ``config.integrator`` ("euler" or "implicitfast"), Newton with
    ``config.solver_iterations`` / ``config.ls_iterations``, pyramidal cone, impratio 1."""
    integrators = {"euler": mujoco.mjtIntegrator.mjINT_EULER,
                   "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST}
    if config.integrator not in integrators:
        raise ValueError(f"integrator {config.integrator!r}: choose one of {sorted(integrators)}")
    opt = spec.option
    opt.timestep = config.sim_dt
    opt.iterations = config.solver_iterations
    opt.ls_iterations = config.ls_iterations
    opt.integrator = integrators[config.integrator]
    opt.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
    opt.impratio = 1.0


def strip_visuals(spec: mujoco.MjSpec) -> None:
    """Deletes mesh geoms, meshes, textures and materials (no effect on physics when every body has an
    explicit inertial); keeps per-env model copies for domain randomisation small."""
    for g in list(spec.geoms):
        if g.type == mujoco.mjtGeom.mjGEOM_MESH:
            spec.delete(g)
        else:
            g.material = ""
    for item in list(spec.meshes) + list(spec.textures) + list(spec.materials):
        spec.delete(item)


def feet_only_contacts(spec: mujoco.MjSpec, feet, floor: str = "floor") -> None:
    """Only the ``feet`` geoms (MjsGeom objects) collide, and only with the ``floor`` geom; margins 0.

    floor: contype 1 / conaffinity 0; feet: contype 0 / conaffinity 1 (so feet never touch each other);
    every other geom: contype = conaffinity = 0.
    """
    feet = list(feet)  # keeps the wrappers alive: the identity test below relies on pybind's instance registry
    for g in spec.geoms:
        g.margin = 0.0
        if g.name == floor:
            g.contype, g.conaffinity = 1, 0
        elif any(g is f for f in feet):
            g.contype, g.conaffinity = 0, 1
        else:
            g.contype, g.conaffinity = 0, 0


def sensor_index(model: mujoco.MjModel) -> dict[str, tuple[int, int]]:
    """``{sensor name: (adr, dim)}`` into ``sensordata``; the same layout in MuJoCo and MJX."""
    return {model.sensor(i).name: (int(model.sensor_adr[i]), int(model.sensor_dim[i])) for i in range(model.nsensor)}

