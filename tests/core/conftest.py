"""Fixtures for the kernel tests: the three shim backends over the same numpy inputs."""

from __future__ import annotations

import os
import sys

import pytest

from unilab_jax import xp as shim

# The test modules import core_helpers / core_cases from this folder (also under --import-mode=importlib).
_HERE = os.path.dirname(os.path.abspath(__file__))
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)

BACKENDS = ("numpy", "jax", "mlx")


@pytest.fixture(params=BACKENDS)
def backend(request: pytest.FixtureRequest) -> shim.Backend:
    """Each shim backend in turn (the kernels find it from their inputs)."""
    return shim.get(request.param)
