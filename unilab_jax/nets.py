"""Networks as plain parameter pytrees, the same code on numpy, jax and mlx.

``init(key, sizes, xp)`` returns ``[{"w": [in, out], "b": [out]}, ...]``; ``apply(params, x)`` runs
the MLP with the backend of ``params``. Parameters convert losslessly between backends with
``convert(params, xp)`` (float32 everywhere).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from unilab_jax import xp as shim

ACTIVATIONS = shim.ACTIVATIONS


def init(key: Any, sizes: Sequence[int], xp: shim.Backend | None = None, final_scale: float = 1.0,
         layer_norm: bool = False) -> list[dict[str, Any]]:
    """MLP parameters for layer sizes ``[in, h1, ..., out]``.

    Weights use LeCun-normal scaled by sqrt(2) for hidden layers (He init) and ``final_scale`` for the
    output layer; biases start at zero. With ``layer_norm`` every hidden layer carries a LayerNorm
    scale/offset (``g``, ``o``).
    """
    xp = xp or shim.namespace(key)
    if len(sizes) < 2 or any(int(s) <= 0 for s in sizes):
        raise ValueError(f"an MLP needs at least two positive layer sizes, got {list(sizes)}")
    keys = xp.random.split(key, len(sizes) - 1)
    params = []
    for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        last = i == len(sizes) - 2
        scale = (final_scale if last else math.sqrt(2.0)) / math.sqrt(n_in)
        layer = {"w": xp.random.normal(keys[i], (n_in, n_out)) * scale, "b": xp.zeros((n_out,), dtype=xp.float32)}
        if layer_norm and not last:
            layer["g"] = xp.ones((n_out,), dtype=xp.float32)
            layer["o"] = xp.zeros((n_out,), dtype=xp.float32)
        params.append(layer)
    return params


def apply(params: list[dict[str, Any]], x: Any, activation: str = "elu") -> Any:
    """Runs the MLP on ``x`` [..., in] -> [..., out]; hidden layers use ``activation`` (``xp.dense``)."""
    xp = shim.namespace(params[0]["w"], x)
    last = len(params) - 1
    for i, layer in enumerate(params):
        x = xp.dense(x, layer["w"], layer["b"], layer.get("g"), layer.get("o"), activation if i < last else "identity")
    return x


def convert(tree: Any, xp: shim.Backend) -> Any:
    """Copies every array leaf of ``tree`` to backend ``xp`` through numpy (lossless for float32)."""

    def leaf(a: Any) -> Any:
        if isinstance(a, int | float | bool) or a is None:
            return a
        return xp.from_numpy(shim.namespace(a).asnumpy(a))

    return shim.tree_map(leaf, tree)


def to_numpy(tree: Any) -> Any:
    """Every array leaf as a numpy array (jax leaves come back in one transfer, not one per leaf)."""
    leaves = shim.tree_leaves(tree)
    if any(type(a).__module__.startswith("jax") for a in leaves):
        import jax

        tree = jax.device_get(tree)
    return convert(tree, shim.get("numpy"))


def num_params(tree: Any) -> int:
    return int(sum(np.prod(np.shape(x)) for x in shim.tree_leaves(tree)))
