"""The kernels use only the array API standard plus the shim's extras: run them all on array_api_strict.

A test-only backend wraps ``array_api_strict``; the shim finds it through ``owns()`` because its module
root is not one of the built-in ones.
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from core_cases import CASE_IDS, CASES
from core_helpers import assert_close, put

from unilab_jax import xp as shim

strict = pytest.importorskip("array_api_strict")

StrictArray = type(strict.asarray(0.0))


class StrictBackend(shim.Backend):
    """Test-only shim backend over ``array_api_strict``: no extras beyond the shim's base class."""

    name = "strict"
    ns = strict
    float32, int32, uint32, bool = strict.float32, strict.int32, strict.uint32, strict.bool

    def owns(self, x):
        return isinstance(x, StrictArray)

    def asnumpy(self, x):
        return np.from_dlpack(x)  # array_api_strict arrays refuse __array__; DLPack is standard


@pytest.fixture(scope="module")
def strict_backend():
    shim.register_backend("strict", StrictBackend)
    backend = shim.get("strict")  # instantiated, so namespace() can find it through owns()
    yield backend
    # Leave the registry as it was for other test modules.
    shim._INSTANCES.pop("strict", None)
    shim._FACTORIES.pop("strict", None)


def test_namespace_finds_the_strict_backend(strict_backend):
    x = strict.asarray([1.0, 2.0], dtype=strict.float32)
    assert shim.namespace(x) is strict_backend
    with pytest.raises(TypeError, match="two backends"):
        shim.namespace(x, np.zeros(2, np.float32))


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_kernels_run_on_array_api_strict(strict_backend, case):
    arrays, static = case.make(np.random.default_rng(zlib.crc32(case.name.encode())))
    got = case.fn(*put(strict_backend, arrays), **static)
    expected = case.fn(*put(shim.get("numpy"), arrays), **static)
    for leaf in shim.tree_leaves(got):
        assert isinstance(leaf, StrictArray) and leaf.dtype == strict.float32
    assert_close(got, expected, rtol=1e-6, atol=1e-6)
