"""Temporal 1-D convolutions and HORA's adaptation module, as plain pytrees on numpy, jax and mlx.

The convolution is written as im2col (strided slices, concatenated, then one matmul), so the same
code runs in the numpy workers, inside ``jax.jit`` and on MLX without a backend convolution op.

Adaptation module (Qi et al. 2022, the "ProprioAdaptTConv" of HORA): each history frame goes
through a per-step MLP with ReLU after every layer, then temporal convolutions with ReLU mix the
frames (valid padding; the first has stride 2, the others stride 1, as in HORA, so strides need not
be stored next to the arrays that the weight channel publishes), then a linear projection of the
flattened result gives the (pre-tanh) latent.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from unilab_jax import nets
from unilab_jax import xp as shim


def conv1d_init(key: Any, in_channels: int, out_channels: int, kernel: int, xp: shim.Backend) -> dict[str, Any]:
    """``{"w": [kernel, in, out], "b": [out]}`` with He-normal weights (fan-in ``kernel * in``), zero bias."""
    scale = math.sqrt(2.0) / math.sqrt(kernel * in_channels)
    return {"w": xp.random.normal(key, (kernel, in_channels, out_channels)) * scale,
            "b": xp.zeros((out_channels,), dtype=xp.float32)}


def conv_length(length: int, kernel: int, stride: int) -> int:
    """Output length of a valid (unpadded) convolution."""
    return (length - kernel) // stride + 1


def conv1d(params: dict[str, Any], x: Any, stride: int = 1) -> Any:
    """Valid 1-D cross-correlation (torch's ``Conv1d`` with padding 0, channels last).

    x: [..., L, C_in]; params["w"]: [k, C_in, C_out]. Returns [..., L_out, C_out] with
    ``L_out = (L - k) // stride + 1`` and ``out[t, o] = b[o] + sum_{j, c} w[j, c, o] x[t * stride + j, c]``.
    """
    w, b = params["w"], params["b"]
    xp = shim.namespace(w, x)
    k, c_in, c_out = (int(s) for s in w.shape)
    length = int(x.shape[-2])
    out_len = conv_length(length, k, stride)
    if out_len < 1:
        raise ValueError(f"a length-{length} sequence is shorter than the kernel ({k})")
    span = stride * (out_len - 1) + 1
    patches = xp.concat([x[..., j:j + span:stride, :] for j in range(k)], axis=-1)  # [..., L_out, k * C_in]
    return xp.matmul(patches, xp.reshape(w, (k * c_in, c_out))) + b


def adaptation_init(key: Any, frame_dim: int, z_dim: int, history_len: int, xp: shim.Backend,
                    hidden: Sequence[int] = (32, 32), channels: int = 32,
                    kernels: Sequence[int] = (9, 5, 5)) -> dict[str, Any]:
    """Parameters of the adaptation module for ``history_len`` frames of ``frame_dim`` features.

    Raises ValueError when the history is too short for the convolutions.
    """
    length = history_len
    for i, k in enumerate(kernels):
        length = conv_length(length, k, 2 if i == 0 else 1)
        if length < 1:
            raise ValueError(f"history_len {history_len} is too short for temporal kernels {tuple(kernels)}")
    keys = xp.random.split(key, len(kernels) + 2)
    convs = []
    c_in = hidden[-1]
    for i, k in enumerate(kernels):
        convs.append(conv1d_init(keys[i + 2], c_in, channels, k, xp))
        c_in = channels
    return {"embed": nets.init(keys[0], [frame_dim, *hidden], xp),
            "convs": convs,
            "proj": nets.init(keys[1], [c_in * length, z_dim], xp)}


def adaptation_apply(params: dict[str, Any], history: Any) -> Any:
    """history: [..., H, frame_dim] (oldest frame first) -> [..., Z] pre-tanh latent."""
    xp = shim.namespace(params["proj"][0]["w"], history)
    h = xp.relu(nets.apply(params["embed"], history, activation="relu"))
    for i, layer in enumerate(params["convs"]):
        h = xp.relu(conv1d(layer, h, stride=2 if i == 0 else 1))
    lead = tuple(history.shape[:-2])
    h = xp.reshape(h, (*lead, int(h.shape[-2]) * int(h.shape[-1])))
    return nets.apply(params["proj"], h)
