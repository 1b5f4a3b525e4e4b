"""The notebooks of experiments/notebooks run top to bottom (nbclient, the venv's own kernel) with the small
budgets their first cell reads from UNILAB_NOTEBOOK_BUDGET=ci, and produce what they promise: a learning
curve image, numbers, a rendered clip. They are stored without outputs."""

from __future__ import annotations

import math
import os
import pathlib
import re

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = pathlib.Path(__file__).resolve().parents[1] / "experiments" / "notebooks"


def _execute(name: str, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> tuple[list, str]:
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code), "stored outputs"
    monkeypatch.setenv("UNILAB_NOTEBOOK_BUDGET", "ci")
    monkeypatch.setenv("UNILAB_NOTEBOOK_RUNS", str(tmp_path))
    monkeypatch.setenv("MUJOCO_GL", os.environ.get("MUJOCO_GL", "egl"))
    # "python3" is ipykernel's native kernel; jupyter_client starts it with this interpreter (the venv's).
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    text = "".join(o.get("text", "") for o in outputs if o.get("output_type") == "stream")
    return outputs, text


def _has_png(outputs: list) -> bool:
    return any("image/png" in o.get("data", {}) for o in outputs)


def _clip_frames(outputs: list, text: str, most: int) -> None:
    """An embedded video of one episode, cut at ``most`` steps (an earlier fall or termination ends it)."""
    assert any("<video" in o.get("data", {}).get("text/html", "") for o in outputs)
    match = re.search(r"clip: (\d+) frames of 320x240", text)
    assert match and 10 <= int(match.group(1)) <= most, text[-2000:]


# The quick starts' CI budgets, final evaluation (8 envs) on the 2-core VM: JAX 30k env steps, seeds 0-5:
# 167, 197, 156, 129, 188, 185; MLX 20k, seeds 0-3: 93, 105, 138, 96 (the notebooks run seed 0). Random
# policy ~35; the checks ask for 55 (38 below the worst seed).
@pytest.mark.parametrize("name", ["quickstart.ipynb", "mlx_quickstart.ipynb"])
def test_quickstart_notebooks(tmp_path, monkeypatch, name):
    outputs, text = _execute(name, tmp_path, monkeypatch)
    assert _has_png(outputs)
    final = re.search(r"final evaluation return: ([-0-9.]+) after (\d+) env steps", text)
    assert final and float(final.group(1)) > 55.0 and int(final.group(2)) >= 20_000, text[-3000:]
    _clip_frames(outputs, text, most=100)
    logdir = tmp_path / ("ppo_cartpole_mlx" if "mlx" in name else "ppo_cartpole")
    assert (logdir / "policy.mp4").stat().st_size > 1000 and (logdir / "summary.json").is_file()


def test_locomotion_notebook(tmp_path, monkeypatch):
    outputs, text = _execute("locomotion.ipynb", tmp_path, monkeypatch)
    metric = re.search(r"tracking error ([0-9.]+) m/s, yaw-rate error ([0-9.]+) rad/s, fall rate ([0-9.]+)", text)
    assert metric, text[-3000:]
    assert all(math.isfinite(float(v)) for v in metric.groups()) and 0 <= float(metric.group(3)) <= 1
    assert _has_png(outputs)  # the per-term reward plot
    terms = re.findall(r"^\s+(\w+)\s+([-0-9.]+)$", text, flags=re.MULTILINE)
    assert {"tracking_lin_vel", "tracking_ang_vel"} <= {t for t, _ in terms}
    _clip_frames(outputs, text, most=50)
