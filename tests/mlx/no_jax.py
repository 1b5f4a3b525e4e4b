"""Runs a script in a fresh interpreter and asserts it finished without importing jax, jaxlib or optax."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_CHECK = """
roots = ('jax', 'jaxlib', 'optax')
loaded = [m for m, v in sys.modules.items() if v is not None and m.split('.')[0] in roots]
assert not loaded, loaded
print('ok')
"""


def assert_runs_without_jax(script: str) -> None:
    """``script`` (which must ``import sys``) then the check, with the checkout on the path."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    res = subprocess.run([sys.executable, "-c", script + _CHECK], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0 and "ok" in res.stdout, f"exit {res.returncode}\n{res.stdout}\n{res.stderr}"
