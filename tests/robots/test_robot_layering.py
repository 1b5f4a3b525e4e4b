"""unilab_jax.robots imports only numpy, mujoco (+ mujoco_menagerie), zmq, msgpack, the standard library
and the low layers (unilab_jax.xp, unilab_jax.config): checked in a fresh interpreter."""

from __future__ import annotations

import subprocess
import sys

FORBIDDEN = ("jax", "mlx", "unilab_mlx", "unilab_jax.algos", "unilab_jax.training.trainer", "unilab_jax.apps.cli",
             "unilab_jax.runtime", "tasks", "torch")

_SCRIPT = """
import sys, math
from unilab_jax.robots import client, experts, gl, interface, protocol, serve, server, sim
from unilab_jax.robots import manipulation
robot = sim.SimRobot(sim.SimConfig(cameras=(), speed=math.inf, reset_seconds=0.0))
robot.reset(seed=0)
robot.step([0.0] * 7)
print(" ".join(sorted(sys.modules)))
"""


def test_robots_import_no_learner_layers():
    out = subprocess.run([sys.executable, "-c", _SCRIPT], capture_output=True, text=True, timeout=120, check=True)
    loaded = set(out.stdout.split())
    bad = sorted(m for m in loaded if any(m == f or m.startswith(f + ".") for f in FORBIDDEN))
    assert not bad, f"unilab_jax.robots pulled in {bad}"
