"""The render hook (``Task.render_scene``): every locomotion task and cart-pole renders offscreen on the CPU
(MUJOCO_GL=egl on Mesa's software rasteriser in CI), and the frame shows the env asked for.

Rendering runs in a fresh interpreter: the GL backend is fixed when mujoco is first imported, which another
test file of the same pytest process may already have done."""

from __future__ import annotations

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NAMES = ["cartpole_balance", "go1_joystick_flat", "go2_joystick_flat", "g1_walk_flat", "go1_joystick_flat_hist",
         "g1_track"]

_SCRIPT = """
import json, sys
import numpy as np
from unilab_jax.apps import play  # picks MUJOCO_GL=egl before mujoco is imported
import tasks

out = {}
for name in sys.argv[1:]:
    task = tasks.make(name, 2, seed=0)
    task.reset()
    action = np.ones((2, task.spec.action_dim), np.float32)
    action[0] = -1.0
    for _ in range(10):  # opposite actions: the two envs' states part
        task.step(action)
    frames = []
    for env in (0, 1):
        renderer = play.SceneRenderer(task, 96, 72, env=env)
        frames.append(renderer.frame())
        renderer.close()
    task.close()
    out[name] = {"shape": list(frames[0].shape), "dtype": str(frames[0].dtype),
                 "std": [float(f.std()) for f in frames],
                 "diff": float(np.abs(frames[0].astype(int) - frames[1]).mean())}
print(json.dumps(out))
"""


def test_tasks_render_the_env_asked_for():
    done = subprocess.run([sys.executable, "-c", _SCRIPT, *NAMES], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    for name in NAMES:
        r = result[name]
        assert r["shape"] == [72, 96, 3] and r["dtype"] == "uint8", (name, r)
        assert min(r["std"]) > 3, (name, r)  # something drawn, not a blank image
        assert r["diff"] > 0.3, (name, r)  # each frame shows its own env's state (measured: 0.9 to 16)


def _headless_choice(monkeypatch, libraries: set[str], preset: str | None = None) -> str | None:
    """MUJOCO_GL after ``prefer_headless`` on Linux, before mujoco's import, with only ``libraries`` findable."""
    import ctypes.util

    from unilab_jax.robots import gl

    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delitem(sys.modules, "mujoco", raising=False)
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: f"lib{name}.so" if name in libraries else None)
    if preset is None:
        monkeypatch.delenv("MUJOCO_GL", raising=False)
    else:
        monkeypatch.setenv("MUJOCO_GL", preset)
    gl.prefer_headless()
    return os.environ.get("MUJOCO_GL")


def test_headless_backend_only_where_its_library_is(monkeypatch):
    # A backend whose library is missing makes `import mujoco` itself fail (a state-policy evaluation through
    # unilab_jax.apps.play crashed so on a GPU machine without libEGL): choose one only where it can load.
    assert _headless_choice(monkeypatch, {"EGL", "OSMesa"}) == "egl"
    assert _headless_choice(monkeypatch, {"OSMesa"}) == "osmesa"
    assert _headless_choice(monkeypatch, set()) is None
    assert _headless_choice(monkeypatch, set(), preset="glfw") == "glfw"  # the user's choice stands
