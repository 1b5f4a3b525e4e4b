"""Shared by the MLX tests: per-leaf relative errors between two state pytrees, scripts run in a fresh
interpreter, and the check that one finishes without importing jax, jaxlib or optax."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from unilab_jax.xp import tree_paths

ROOT = Path(__file__).resolve().parents[2]
_CHECK = """
roots = ('jax', 'jaxlib', 'optax')
loaded = [m for m, v in sys.modules.items() if v is not None and m.split('.')[0] in roots]
assert not loaded, loaded
print('ok')
"""


def run_python(code: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """``code`` in a fresh interpreter from the checkout's root, with the checkout on the path (text output)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)


def assert_runs_without_jax(script: str) -> None:
    """``script`` (which must ``import sys``) then the check, with the checkout on the path."""
    res = run_python(script + _CHECK)
    assert res.returncode == 0 and "ok" in res.stdout, f"exit {res.returncode}\n{res.stdout}\n{res.stderr}"


def leaf_errors(got: object, want: object) -> dict[str, float]:
    """Per float leaf: max |got - want| / max |want| (paths like ``params/actor/0/w``)."""
    g, w = dict(tree_paths(got)), dict(tree_paths(want))
    assert g.keys() == w.keys()
    out = {}
    for p in w:
        a, b = np.asarray(g[p]), np.asarray(w[p])
        assert a.shape == b.shape, p
        if b.dtype.kind == "f" and b.size:
            out[p] = float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-12))
    return out
