"""What the benchmark records say about the machine they ran on (shared by the bench scripts)."""

from __future__ import annotations

import json
import os
import platform


def cpu_model() -> str:
    """The CPU's model name from ``/proc/cpuinfo`` (Linux), else what ``platform`` knows."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            return next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu)
    except OSError:
        return cpu


def host_info() -> dict:
    """The host, CPU, core count and Python of a CPU-side record (``platform``'s view)."""
    return {"host": platform.node(), "cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "python": platform.python_version()}


def write_json(path: str, result: dict) -> None:
    """Writes a benchmark's result (numpy scalars as floats), creating the folder; says where."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as f:
        json.dump(result, f, indent=2, default=float)
    print(f"wrote {path}")
