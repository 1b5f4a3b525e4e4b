"""Which offscreen OpenGL backend can render here (``MUJOCO_GL`` must be chosen before mujoco is imported).

``find_gl_backend()`` tries each candidate in a fresh interpreter (a failed GL setup can leave a
process unusable) and returns ``(backend, reasons)``: the first one that renders a frame, or None with
each candidate's failure. On Linux without a display: ``egl`` needs libegl1 + libegl-mesa0 +
libgl1-mesa-dri + libopengl0 (Mesa's software rasteriser works); ``osmesa`` needs libosmesa6.
"""

from __future__ import annotations

import ctypes.util
import os
import subprocess
import sys

CANDIDATES = ("egl", "osmesa")

_PROBE = """
import mujoco
m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><light pos="0 0 1"/><geom size=".1"/></worldbody></mujoco>')
d = mujoco.MjData(m)
mujoco.mj_forward(m, d)
with mujoco.Renderer(m, 16, 16) as r:
    r.update_scene(d)
    assert r.render().shape == (16, 16, 3)
"""


def probe(backend: str, timeout_s: float = 60.0) -> str | None:
    """None if ``MUJOCO_GL=backend`` renders a frame in a fresh interpreter, else the reason it does not."""
    env = {**os.environ, "MUJOCO_GL": backend}
    try:
        out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True,
                             timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return f"{backend}: no frame within {timeout_s:.0f} s"
    if out.returncode == 0:
        return None
    last = (out.stderr.strip().splitlines() or [f"exit status {out.returncode}"])[-1]
    return f"{backend}: {last}"


def find_gl_backend(candidates: tuple[str, ...] = CANDIDATES) -> tuple[str | None, list[str]]:
    """(first working backend or None, failure reasons of the ones tried before it)."""
    reasons = []
    for backend in candidates:
        reason = probe(backend)
        if reason is None:
            return backend, reasons
        reasons.append(reason)
    return None, reasons


# MUJOCO_GL backend -> the shared library it loads when mujoco is imported (a backend whose library is missing
# makes ``import mujoco`` itself fail, rendering or not).
LIBRARIES = {"egl": "EGL", "osmesa": "OSMesa"}


def prefer_headless() -> None:
    """On Linux, ``MUJOCO_GL=egl`` unless the variable is already set: offscreen rendering without a display
    (a GPU driver's EGL, or Mesa's software one on CPU-only machines); ``osmesa`` where only OSMesa is
    installed; nothing where neither library is, so that mujoco still imports and only rendering fails (with
    the renderer's own error). Only has an effect before mujoco is imported, so callers run it first
    (``unilab_jax.apps.play`` on import, the CLI when ``--video_every`` is set)."""
    if not sys.platform.startswith("linux") or "mujoco" in sys.modules or "MUJOCO_GL" in os.environ:
        return
    for backend in CANDIDATES:
        if ctypes.util.find_library(LIBRARIES[backend]) is not None:
            os.environ["MUJOCO_GL"] = backend
            return
