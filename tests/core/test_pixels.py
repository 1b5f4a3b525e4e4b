"""Image kernels: the shim's conv2d and unilab_jax.core.pixels (DrQ shift, encoder) on hand-computed cases,
on numpy, jax and mlx, and across backends on random inputs (values and, on jax/mlx, gradients)."""

from __future__ import annotations

import numpy as np
import pytest

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.core import pixels

BACKENDS = ["numpy", "jax", "mlx"]


def test_conv2d_hand_computed(backend):
    xp = backend  # each shim backend in turn (tests/core/conftest.py)
    x = np.arange(25, dtype=np.float32).reshape(1, 5, 5, 1)  # x[r, c] = 5 r + c
    w = np.zeros((3, 3, 2, 2), np.float32)
    w[:, :, 0, 0] = 1.0  # output 0: the window's sum = 9 x its centre (x is linear)
    w[1, 1, 1, 1] = -2.0  # output 1: -2 x the centre of input channel 1
    x2 = np.concatenate([x, 10.0 * x], axis=-1)
    out = xp.asnumpy(xp.conv2d(xp.asarray(x2), xp.asarray(w), 1))
    assert out.shape == (1, 3, 3, 2)
    centres = np.array([[6, 7, 8], [11, 12, 13], [16, 17, 18]], np.float32)
    np.testing.assert_allclose(out[0, :, :, 0], 9.0 * centres, rtol=1e-6)
    np.testing.assert_allclose(out[0, :, :, 1], -20.0 * centres, rtol=1e-6)
    # stride 2: the windows centred on (1, 1), (1, 3), (3, 1), (3, 3)
    out = xp.asnumpy(xp.conv2d(xp.asarray(x2), xp.asarray(w), 2))
    np.testing.assert_allclose(out[0, :, :, 0], 9.0 * np.array([[6, 8], [16, 18]], np.float32), rtol=1e-6)
    # a non-symmetric kernel tells cross-correlation (no flip) from convolution
    k = np.zeros((3, 3, 1, 1), np.float32)
    k[0, 2, 0, 0] = 1.0  # picks x[r - 1, c + 1] relative to the centre
    out = xp.asnumpy(xp.conv2d(xp.asarray(x), xp.asarray(k), 1))
    np.testing.assert_array_equal(out[0, :, :, 0], centres - 5 + 1)


def test_conv2d_backends_agree_on_random_inputs_and_gradients():
    jax = pytest.importorskip("jax")
    mx = pytest.importorskip("mlx.core")
    rng = np.random.default_rng(0)
    x = rng.normal(size=(3, 11, 9, 4)).astype(np.float32)
    w = rng.normal(size=(3, 3, 4, 5)).astype(np.float32)
    g = rng.normal(size=(3, 5, 4, 5)).astype(np.float32)  # cotangent of the stride-2 output
    np_xp, jx, mlx = shim.get("numpy"), shim.get("jax"), shim.get("mlx")
    for stride in (1, 2):
        want = np_xp.conv2d(x, w, stride)
        np.testing.assert_allclose(np.asarray(jx.conv2d(jx.asarray(x), jx.asarray(w), stride)), want, atol=1e-5)
        np.testing.assert_allclose(np.array(mlx.conv2d(mlx.asarray(x), mlx.asarray(w), stride)), want, atol=1e-5)
    grads_j = jax.grad(lambda a, b: (jx.conv2d(a, b, 2) * g).sum(), argnums=(0, 1))(jx.asarray(x), jx.asarray(w))
    grads_m = mx.grad(lambda a, b: (mlx.conv2d(a, b, 2) * mx.array(g)).sum(), argnums=(0, 1))(
        mlx.asarray(x), mlx.asarray(w))
    for gj, gm in zip(grads_j, grads_m, strict=True):
        np.testing.assert_allclose(np.array(gm), np.asarray(gj), atol=1e-4)
    # the weight gradient by hand: sum over batch and output positions of g * the input window
    windows = np.lib.stride_tricks.sliding_window_view(x, (3, 3), axis=(1, 2))[:, ::2, ::2]  # [B, 5, 4, Cin, 3, 3]
    np.testing.assert_allclose(np.asarray(grads_j[1]), np.einsum("bhwcij,bhwo->ijco", windows, g), atol=1e-4)


def test_random_shift_hand_computed(backend):
    xp = backend
    img = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9]], np.uint8)[None, :, :, None]
    img = np.concatenate([img, img + 100], axis=0)  # two images
    shifts = np.array([[0, 2], [1, 1]], np.int32)  # image 0: one row up, one column right; image 1: none
    out = xp.asnumpy(pixels.random_shift(xp.asarray(img), xp.asarray(shifts), pad=1))
    assert out.dtype == np.uint8 and out.shape == img.shape
    # out[i, j] = img[clip(i - 1), clip(j + 1)]: the edge row / column repeats
    np.testing.assert_array_equal(out[0, :, :, 0], [[2, 3, 3], [2, 3, 3], [5, 6, 6]])
    np.testing.assert_array_equal(out[1], img[1])
    far = xp.asnumpy(pixels.random_shift(xp.asarray(img), xp.asarray(np.array([[4, 0], [0, 3]], np.int32)), pad=2))
    np.testing.assert_array_equal(far[0, :, :, 0], [[7, 7, 7]] * 3)  # rows clip(i + 2) = 2, columns clip(j - 2) = 0
    np.testing.assert_array_equal(far[1, :, :, 0], [[102, 103, 103]] * 3)  # rows clip(i - 2), columns clip(j + 1)


def test_random_shift_equals_edge_pad_and_crop():
    rng = np.random.default_rng(1)
    img = rng.integers(0, 256, size=(4, 10, 7, 6), dtype=np.uint8)
    shifts = rng.integers(0, 9, size=(4, 2)).astype(np.int32)
    padded = np.pad(img, ((0, 0), (4, 4), (4, 4), (0, 0)), mode="edge")
    want = np.stack([padded[b, s[0]:s[0] + 10, s[1]:s[1] + 7] for b, s in enumerate(shifts)])
    for name in BACKENDS:
        xp = shim.get(name)
        np.testing.assert_array_equal(xp.asnumpy(pixels.random_shift(xp.asarray(img), xp.asarray(shifts), 4)), want)


def test_flat_dim_and_encoder_shapes():
    assert pixels.conv_out(64, 2) == 31 and pixels.conv_out(31, 1) == 29
    assert pixels.flat_dim((64, 64, 6), (32, 32, 32, 32), (2, 1, 1, 1)) == 25 * 25 * 32
    with pytest.raises(ValueError, match="too small"):
        pixels.flat_dim((8, 8, 3), (4, 4, 4), (2, 2, 1))
    np_xp = shim.get("numpy")
    params = pixels.encoder_init(np_xp.random.key(0), (12, 10, 6), (8, 4), (2, 1), 5, np_xp)
    assert [c["w"].shape for c in params["convs"]] == [(3, 3, 6, 8), (3, 3, 8, 4)]
    assert params["linear"]["w"].shape == (3 * 2 * 4, 5)  # 12 x 10 -> 5 x 4 -> 3 x 2, 4 channels
    feat = pixels.encode(params, np.full((2, 12, 10, 6), 255, np.uint8), (2, 1))
    assert feat.shape == (2, 5) and feat.dtype == np.float32 and np.all(np.abs(feat) < 1.0)
    np.testing.assert_allclose(pixels.to_float(np.array([0, 255], np.uint8)), [-0.5, 0.5])


def test_encoder_flatten_order_by_hand():
    """One 1x1-channel convolution picking the window's centre, a linear layer reading one flattened
    position: the feature is the pixel at that (row, column), so every backend flattens rows, then columns,
    then channels (NHWC)."""
    np_xp = shim.get("numpy")
    params = pixels.encoder_init(np_xp.random.key(0), (5, 6, 1), (2,), (1,), 2, np_xp)
    w = np.zeros((3, 3, 1, 2), np.float32)
    w[1, 1, 0, 0], w[1, 1, 0, 1] = 1.0, 2.0
    params["convs"][0] = {"w": w, "b": np.full((2,), 0.5, np.float32)}
    lin = np.zeros((3 * 4 * 2, 2), np.float32)
    lin[(1 * 4 + 2) * 2 + 1, 0] = 1.0  # row 1, column 2, channel 1 of the 3 x 4 x 2 map
    params["linear"] = {"w": lin, "b": np.zeros((2,), np.float32)}
    img = np.zeros((1, 5, 6, 1), np.uint8)
    img[0, 2, 3, 0] = 255  # the centre of output position (1, 2)
    for name in BACKENDS:
        xp = shim.get(name)
        feat = xp.asnumpy(pixels.encode(nets.convert(params, xp), xp.asarray(img), (1,)))
        # channel 1 there: relu(2 x 0.5 + 0.5) = 1.5 (elsewhere relu(-0.5) = 0); the linear output [1.5, 0]
        # -> LayerNorm over 2 entries -> [1, -1] -> tanh (another flatten order reads a 0: [0, 0])
        np.testing.assert_allclose(feat, np.tanh([[1.0, -1.0]]), atol=1e-5)


def test_encoder_backends_agree():
    pytest.importorskip("jax")
    pytest.importorskip("mlx.core")
    np_xp = shim.get("numpy")
    params = pixels.encoder_init(np_xp.random.key(3), (16, 14, 6), (8, 8, 8), (2, 1, 1), 7, np_xp)
    img = np.random.default_rng(2).integers(0, 256, size=(3, 16, 14, 6), dtype=np.uint8)
    want = pixels.encode(params, img, (2, 1, 1))
    for name in ("jax", "mlx"):
        xp = shim.get(name)
        got = xp.asnumpy(pixels.encode(nets.convert(params, xp), xp.asarray(img), (2, 1, 1)))
        np.testing.assert_allclose(got, want, atol=1e-5)
    assert np.std(want) > 0.1  # non-degenerate features
