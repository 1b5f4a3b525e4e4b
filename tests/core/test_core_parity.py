"""Every kernel gives the same values on numpy, jax and mlx from the same numpy inputs (float32 on
every backend, compared with a float64 numpy evaluation of the same kernel)."""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from core_cases import CASE_IDS, CASES
from core_helpers import assert_close, put, to_np

from unilab_jax import xp as shim


def _f64(tree):
    return shim.tree_map(lambda a: a if a.dtype == np.bool_ else np.asarray(a, np.float64),
                         shim.tree_map(np.asarray, tree))


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_same_values_on_every_backend(case, backend):
    arrays, static = case.make(np.random.default_rng(zlib.crc32(case.name.encode())))
    expected = case.fn(*_f64(arrays), **static)
    got = case.fn(*put(backend, arrays), **static)
    for leaf in shim.tree_leaves(got):
        assert shim.namespace(leaf) is backend
        assert leaf.dtype == backend.float32, f"{case.name} returned {leaf.dtype} on {backend.name}"
    assert_close(got, expected, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_mlx_compiled_matches_eager(case):
    mlx = shim.get("mlx")
    arrays, static = case.make(np.random.default_rng(1))
    args = put(mlx, arrays)
    compiled = mlx.jit(lambda *a: case.fn(*a, **static))
    assert_close(to_np(compiled(*args)), to_np(case.fn(*args, **static)), rtol=1e-6, atol=1e-6)
