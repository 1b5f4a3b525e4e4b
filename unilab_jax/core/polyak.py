"""Polyak (exponential moving average) update of target networks."""

from __future__ import annotations

from typing import Any

from unilab_jax import xp as shim


def polyak(target_tree: Any, online_tree: Any, tau: float) -> Any:
    """``target <- (1 - tau) * target + tau * online`` leaf by leaf (trees of identical structure;
    any leaf shapes). tau: python float or scalar. Returns the new target tree."""
    leaves = shim.tree_leaves(target_tree)
    xp = shim.namespace(*leaves[:1])
    return xp.tree_map(lambda t, o: (1.0 - tau) * t + tau * o, target_tree, online_tree)
