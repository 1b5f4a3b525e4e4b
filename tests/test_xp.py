"""The shim: backend detection, keyed randomness, extras, and import isolation."""

import subprocess
import sys

import numpy as np
import pytest

from unilab_jax import xp as shim

BACKENDS = ["numpy", "jax", "mlx"]


@pytest.fixture(params=BACKENDS)
def xp(request):
    return shim.get(request.param)


def test_namespace_detects_each_backend(xp):
    a = xp.from_numpy(np.ones(3, np.float32))
    assert shim.namespace(a) is xp
    assert shim.namespace(a, 1.0, None) is xp


def test_namespace_rejects_mixed_backends():
    with pytest.raises(TypeError, match="two backends"):
        shim.namespace(np.ones(2), shim.get("mlx").from_numpy(np.ones(2)))


def test_unknown_backend_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown array backend"):
        shim.get("torch")


def test_keyed_random_is_deterministic_and_keys_differ(xp):
    k = xp.random.key(3)
    a = xp.asnumpy(xp.random.normal(k, (64,)))
    b = xp.asnumpy(xp.random.normal(k, (64,)))
    np.testing.assert_array_equal(a, b)
    k1, k2 = xp.random.split(k, 2)
    c = xp.asnumpy(xp.random.normal(k1, (64,)))
    d = xp.asnumpy(xp.random.normal(k2, (64,)))
    assert not np.allclose(c, d)
    u = xp.asnumpy(xp.random.uniform(k1, (1000,), -2.0, 3.0))
    assert u.min() >= -2.0 and u.max() < 3.0 and abs(u.mean() - 0.5) < 0.2
    n = xp.asnumpy(xp.random.normal(k2, (20000,)))
    assert abs(n.mean()) < 0.05 and abs(n.std() - 1.0) < 0.05
    r = xp.asnumpy(xp.random.randint(k1, (500,), 0, 4))
    assert set(np.unique(r)) == {0, 1, 2, 3}


def test_extras_agree_across_backends(xp):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(5, 7)).astype(np.float32) * 5
    a = xp.from_numpy(x)
    ref = shim.get("numpy")
    for name in ("logsumexp", "softmax", "log_softmax"):
        np.testing.assert_allclose(xp.asnumpy(getattr(xp, name)(a, axis=-1)), getattr(ref, name)(x, axis=-1),
                                   rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(xp.asnumpy(xp.softplus(a)), np.logaddexp(x, 0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(xp.asnumpy(xp.elu(a)), np.where(x > 0, x, np.expm1(np.minimum(x, 0))),
                               rtol=1e-5, atol=1e-6)
    idx = xp.from_numpy(np.array([0, 2, 1], np.int32))
    np.testing.assert_array_equal(xp.asnumpy(xp.one_hot(idx, 3)), np.eye(3, dtype=np.float32)[[0, 2, 1]])


def test_cumulative_sum_and_take_along_axis_agree_with_numpy(xp):
    # Array API names the kernels use (c51.categorical_projection_uniform); MLX's cumulative_sum is adapted.
    x = np.arange(12, dtype=np.float32).reshape(2, 2, 3) - 4.5
    a = xp.from_numpy(x)
    for axis, initial in ((-1, False), (-1, True), (1, True), (0, False)):
        np.testing.assert_array_equal(xp.asnumpy(xp.cumulative_sum(a, axis=axis, include_initial=initial)),
                                      np.cumulative_sum(x, axis=axis, include_initial=initial))
    np.testing.assert_array_equal(xp.asnumpy(xp.cumulative_sum(a[0, 0, :], include_initial=True)),
                                  [0.0, -4.5, -8.0, -10.5])
    idx = np.array([[[2, 0, 0, 1]], [[1, 1, 2, 0]]], np.int32)  # [2, 1, 4]: broadcast over axis 1
    np.testing.assert_array_equal(xp.asnumpy(xp.take_along_axis(a, xp.from_numpy(idx), axis=-1)),
                                  np.take_along_axis(x, idx, axis=-1))
    np.testing.assert_array_equal(xp.asnumpy(xp.floor(a)), np.floor(x))
    np.testing.assert_array_equal(xp.asnumpy(xp.ceil(a)), np.ceil(x))


def test_scan_matches_python_loop(xp):
    xs = np.arange(1.0, 6.0, dtype=np.float32)

    def f(c, x):
        return c * 0.5 + x, c + x

    for reverse in (False, True):
        carry, ys = xp.scan(f, xp.from_numpy(np.float32(0.0)), xp.from_numpy(xs), reverse=reverse)
        c, want = np.float32(0.0), np.zeros_like(xs)
        for t in (range(4, -1, -1) if reverse else range(5)):
            c, want[t] = f(c, xs[t])
        np.testing.assert_allclose(xp.asnumpy(ys), want, rtol=1e-6)
        np.testing.assert_allclose(float(xp.asnumpy(carry)), c, rtol=1e-6)


@pytest.mark.parametrize("name", ["jax", "mlx"])
def test_value_and_grad_with_aux(name):
    xp = shim.get(name)
    w = xp.from_numpy(np.array([1.0, -2.0, 3.0], np.float32))

    def f(p, s):
        return xp.sum(xp.square(p["w"])) * s, {"n": xp.sum(p["w"])}

    (val, aux), grads = xp.value_and_grad(f, has_aux=True)({"w": w}, 2.0)
    assert float(xp.asnumpy(val)) == pytest.approx(28.0)
    assert float(xp.asnumpy(aux["n"])) == pytest.approx(2.0)
    np.testing.assert_allclose(xp.asnumpy(grads["w"]), [4.0, -8.0, 12.0])


def test_materialize_keeps_values_structure_and_gradients(xp):
    x = np.arange(6, dtype=np.float32).reshape(2, 3)
    tree = (xp.from_numpy(x), {"s": xp.from_numpy(np.float32(2.0))})
    out = xp.jit(xp.materialize)(tree)
    np.testing.assert_array_equal(xp.asnumpy(out[0]), x)
    assert float(xp.asnumpy(out[1]["s"])) == 2.0
    if xp.name == "numpy":
        return
    grad = xp.value_and_grad(lambda a: xp.sum(xp.square(xp.materialize(a))))(tree[0])[1]
    np.testing.assert_allclose(xp.asnumpy(grad), 2 * x)


def test_jax_materialize_is_a_barrier_in_the_compiled_program():
    jx = shim.get("jax")
    text = jx.jit(lambda a: jx.materialize(jx.exp(a)) * 2.0).lower(jx.from_numpy(np.ones(3, np.float32))).as_text()
    assert "optimization_barrier" in text


def test_numpy_has_no_autodiff():
    with pytest.raises(NotImplementedError):
        shim.get("numpy").value_and_grad(lambda x: x)


def test_tree_utilities_keep_structure():
    from typing import NamedTuple

    class P(NamedTuple):
        a: object
        b: object

    tree = {"z": [np.ones(2), P(np.zeros(1), 3.0)], "a": None}
    out = shim.tree_map(lambda x: x * 2, tree)
    assert isinstance(out["z"][1], P) and out["a"] is None
    assert [p for p, _ in shim.tree_paths(tree)] == ["z/0", "z/1/a", "z/1/b"]
    with pytest.raises(ValueError, match="mismatch"):
        shim.tree_map(lambda x, y: x, {"a": 1}, {"b": 1})


@pytest.mark.parametrize("module", ["unilab_mlx", "unilab_jax", "unilab_jax.core", "unilab_jax.runtime", "tasks"])
def test_imports_do_not_pull_in_jax(module):
    code = f"import sys; sys.modules['jax'] = None; import {module}; from unilab_jax import xp; xp.get('numpy')"
    if module == "unilab_mlx":
        code += "; xp.get('mlx')"
    subprocess.run([sys.executable, "-c", code], check=True)
