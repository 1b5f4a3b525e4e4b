"""Loading by name: the one way a lower layer reaches a higher one (docs/ARCHITECTURE.md, "Layers").

Registries (algorithms, learners, tasks, shim backends) hold ``"package.module:attribute"`` strings and
import them only when asked, so a table can name modules above it without importing them.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

ALGORITHM_REGISTRY = "unilab_jax.algos"


def load(target: str) -> Any:
    """``"package.module:attribute"`` -> that attribute (the module imported now, if it was not yet)."""
    module, _, attribute = target.partition(":")
    if not attribute:
        raise ValueError(f"{target!r} is not of the form 'package.module:attribute'")
    return getattr(importlib.import_module(module), attribute)


def learner_maker(algo_module: str) -> Callable[..., Any]:
    """An algorithm declaration's ``make_learner(platform, config, spec)``: the learner the algorithm
    registry maps (this declaration, platform) to, looked up by name at call time."""

    def make_learner(platform: str, config: Any, spec: Any) -> Any:
        return load(f"{ALGORITHM_REGISTRY}:make_learner")(algo_module, platform, config, spec)

    return make_learner
