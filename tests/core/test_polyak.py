"""Polyak averaging against optax.incremental_update."""

from __future__ import annotations

import numpy as np
import pytest
from core_helpers import assert_close, f32

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.core.polyak import polyak

optax = pytest.importorskip("optax")


def test_polyak_matches_optax(backend):
    np_backend = shim.get("numpy")
    target = nets.init(np_backend.random.key(0), [7, 16, 3])
    online = nets.init(np_backend.random.key(1), [7, 16, 3])
    target = {"actor": target, "log_alpha": f32(np.array(0.3))}
    online = {"actor": online, "log_alpha": f32(np.array(-0.1))}
    expected = optax.incremental_update(nets.convert(online, shim.get("jax")),
                                        nets.convert(target, shim.get("jax")), 0.005)
    got = polyak(nets.convert(target, backend), nets.convert(online, backend), 0.005)
    assert_close(got, expected, rtol=1e-6, atol=1e-7)
    assert shim.tree_leaves(got)[0].dtype == backend.float32
    assert_close(polyak(target, online, 1.0), online)
