"""The notebooks' install step, shared by the three notebooks of this folder (their first code cell imports it).

Inside a checkout (Jupyter started from a clone, CI) it installs nothing when ``unilab_jax`` and the backend the
notebook needs are importable; elsewhere (Colab, after the cell cloned the repository) it runs
``pip install -e "<checkout>[extras]"``. Either way the checkout comes first on ``sys.path``, so the notebook runs
the code beside it.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]


def install(extras: str, needs: str) -> pathlib.Path:
    """Makes this checkout importable with the ``extras`` it needs (``needs``: the module that says they are
    there, e.g. "jax"); returns the checkout's folder."""
    if importlib.util.find_spec("unilab_jax") is None or importlib.util.find_spec(needs) is None:
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "-e", f"{ROOT}[{extras}]"], check=True)
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))  # this kernel started before an editable install existed
    importlib.invalidate_caches()
    print(f"UniLab-JAX at {ROOT}, Python {sys.executable}")
    return ROOT


def runs_dir() -> pathlib.Path:
    """Where the notebooks write their runs: ``UNILAB_NOTEBOOK_RUNS`` (CI's temporary folder), else
    ``runs/notebooks`` in the checkout."""
    return pathlib.Path(os.environ.get("UNILAB_NOTEBOOK_RUNS", ROOT / "runs" / "notebooks"))
