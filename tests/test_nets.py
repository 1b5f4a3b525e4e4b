"""MLPs run unchanged on every backend; parameters convert losslessly."""

import numpy as np
import pytest

from unilab_jax import nets
from unilab_jax import xp as shim


@pytest.mark.parametrize("activation", ["elu", "relu", "tanh", "silu"])
@pytest.mark.parametrize("layer_norm", [False, True])
def test_apply_agrees_across_backends(activation, layer_norm):
    params = nets.init(shim.get("numpy").random.key(0), [7, 32, 16, 3], layer_norm=layer_norm)
    x = np.random.default_rng(1).normal(size=(11, 7)).astype(np.float32)
    ref = nets.apply(params, x, activation)
    assert ref.shape == (11, 3) and ref.dtype == np.float32
    for name in ("jax", "mlx"):
        xp = shim.get(name)
        out = nets.apply(nets.convert(params, xp), xp.from_numpy(x), activation)
        np.testing.assert_allclose(xp.asnumpy(out), ref, rtol=1e-5, atol=1e-5)


def test_conversion_round_trip_is_bitwise():
    params = nets.init(shim.get("jax").random.key(5), [4, 8, 2])
    for a, b in (("jax", "mlx"), ("mlx", "numpy"), ("numpy", "jax")):
        there = nets.convert(nets.convert(params, shim.get(a)), shim.get(b))
        back = nets.to_numpy(nets.convert(there, shim.get("jax")))
        for x, y in zip(shim.tree_leaves(nets.to_numpy(params)), shim.tree_leaves(back)):
            np.testing.assert_array_equal(x, y)


def test_init_shapes_and_bad_sizes():
    params = nets.init(shim.get("numpy").random.key(0), [5, 4, 2])
    assert [p["w"].shape for p in params] == [(5, 4), (4, 2)]
    assert nets.num_params(params) == 5 * 4 + 4 + 4 * 2 + 2
    with pytest.raises(ValueError):
        nets.init(shim.get("numpy").random.key(0), [5])
    with pytest.raises(ValueError, match="unknown activation"):
        nets.apply(params, np.zeros((1, 5), np.float32), "gelu2")
