"""Image observations: a small convolutional encoder and DrQ's random-shift augmentation, on the shim.

Images are uint8 ``[B, H, W, C]``, channels last (C = 3 x cameras x stacked frames); they stay uint8 until
``to_float`` maps them to ``[-0.5, 0.5]``.

The encoder (Kostrikov, Yarats & Fergus, "Image Augmentation Is All You Need", ICLR 2021, arXiv:2004.13649;
Yarats et al., "Improving Sample Efficiency in Model-Free RL from Images", arXiv:1910.01741): 3x3 VALID
convolutions with ReLU (``channels``, ``strides``), flattened in NHWC order (``reshape(B, -1)``, the same on
every backend), a linear layer to ``feature_dim``, LayerNorm, tanh. Parameters::

    {"convs": [{"w": [3, 3, Cin, Cout], "b": [Cout]}, ...], "linear": {"w": [H'W'C', F], "b": [F]},
     "norm": {"g": [F], "o": [F]}}

The strides are not in the parameters (they are configuration): ``encode`` takes them.

DrQ's augmentation shifts every image by an integer offset in ``[-pad, pad]`` in each axis, with edge
replication at the border (pad by ``pad`` replicating the edge, crop back at the offset). ``random_shift``
is a pure function of the offsets, the caller draws them from its key.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from unilab_jax import xp as shim

KERNEL = 3  # convolution kernel size


def conv_out(size: int, stride: int) -> int:
    """Output length of a VALID ``KERNEL``-wide convolution with ``stride`` over ``size`` pixels."""
    return (size - KERNEL) // stride + 1


def flat_dim(image_shape: Sequence[int], channels: Sequence[int], strides: Sequence[int]) -> int:
    """Width of the flattened last feature map of an image ``(H, W, C)``; raises if it vanishes."""
    h, w = int(image_shape[0]), int(image_shape[1])
    for s in strides:
        h, w = conv_out(h, s), conv_out(w, s)
        if h < 1 or w < 1:
            raise ValueError(f"image {tuple(image_shape)} is too small for {len(strides)} 3x3 convolutions with "
                             f"strides {tuple(strides)}")
    return h * w * int(channels[-1])


def to_float(image: Any) -> Any:
    """uint8 ``[..., H, W, C]`` -> float32 in ``[-0.5, 0.5]``."""
    xp = shim.namespace(image)
    return xp.astype(image, xp.float32) / 255.0 - 0.5


def random_shift(image: Any, shifts: Any, pad: int) -> Any:
    """DrQ's random shift: ``image [B, H, W, C]`` (any dtype), ``shifts [B, 2]`` integers in ``[0, 2 pad]``
    (row, column crop offsets into the edge-padded image) -> ``[B, H, W, C]``, same dtype::

        out[b, i, j] = image[b, clip(i + shifts[b, 0] - pad, 0, H - 1), clip(j + shifts[b, 1] - pad, 0, W - 1)]

    (a gather of indices clamped to the image, which equals padding by ``pad`` with edge replication and
    cropping at the offsets); ``shifts == pad`` everywhere is the identity."""
    xp = shim.namespace(image, shifts)
    b, h, w = (int(n) for n in image.shape[:3])
    shifts = xp.astype(shifts, xp.int32)
    rows = xp.clip(xp.arange(h, dtype=xp.int32)[None, :] + shifts[:, 0:1] - pad, 0, h - 1)  # [B, H]
    cols = xp.clip(xp.arange(w, dtype=xp.int32)[None, :] + shifts[:, 1:2] - pad, 0, w - 1)  # [B, W]
    batch = xp.arange(b, dtype=xp.int32)[:, None, None]
    return image[batch, rows[:, :, None], cols[:, None, :]]


def encoder_init(key: Any, image_shape: Sequence[int], channels: Sequence[int], strides: Sequence[int],
                 feature_dim: int, xp: shim.Backend) -> dict[str, Any]:
    """Encoder parameters for images ``(H, W, C)`` (He-normal convolutions, LeCun-normal linear layer, zero
    biases, LayerNorm scale 1 and offset 0)."""
    if len(channels) != len(strides) or not channels:
        raise ValueError(f"need one stride per convolution, got channels {tuple(channels)}, strides {tuple(strides)}")
    n_flat = flat_dim(image_shape, channels, strides)
    keys = xp.random.split(key, len(channels) + 1)
    convs, c_in = [], int(image_shape[2])
    for i, c_out in enumerate(channels):
        scale = math.sqrt(2.0 / (KERNEL * KERNEL * c_in))
        convs.append({"w": xp.random.normal(keys[i], (KERNEL, KERNEL, c_in, int(c_out))) * scale,
                      "b": xp.zeros((int(c_out),), dtype=xp.float32)})
        c_in = int(c_out)
    linear = {"w": xp.random.normal(keys[-1], (n_flat, feature_dim)) * (1.0 / math.sqrt(n_flat)),
              "b": xp.zeros((feature_dim,), dtype=xp.float32)}
    norm = {"g": xp.ones((feature_dim,), dtype=xp.float32), "o": xp.zeros((feature_dim,), dtype=xp.float32)}
    return {"convs": convs, "linear": linear, "norm": norm}


def encode(params: dict[str, Any], image: Any, strides: Sequence[int]) -> Any:
    """uint8 ``image [B, H, W, C]`` -> features ``[B, F]`` in ``(-1, 1)``."""
    xp = shim.namespace(params["linear"]["w"], image)
    x = to_float(image)
    for layer, stride in zip(params["convs"], strides, strict=True):
        x = xp.relu(xp.conv2d(x, layer["w"], int(stride)) + layer["b"])
    x = xp.matmul(xp.reshape(x, (int(x.shape[0]), -1)), params["linear"]["w"]) + params["linear"]["b"]
    mu = xp.mean(x, axis=-1, keepdims=True)
    var = xp.mean(xp.square(x - mu), axis=-1, keepdims=True)
    x = (x - mu) / xp.sqrt(var + 1e-5) * params["norm"]["g"] + params["norm"]["o"]
    return xp.tanh(x)
