"""RLPD kernels (Ball et al., "Efficient Online Reinforcement Learning with Offline Data", ICML 2023).

* The critic ensemble's target takes the minimum over a random subset of its ``E`` members
  (``subset_indices`` + ``ensemble_members``: only the subset's members are evaluated; redrawn every gradient
  step).
* Critic loss: the mean over members and samples of the squared error to the shared target.
* Symmetric sampling: every minibatch is half online data, half prior data (``symmetric_split``,
  ``compose``).

Shapes: ensemble values ``[E, B]``, subset noise ``u`` ``[E]`` (uniform draws), targets ``[B]``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from unilab_jax import xp as shim


def subset_indices(u: Any, k: int) -> Any:
    """``[k]`` int: the members whose noise ``u`` ``[E]`` is smallest, smallest first (a uniformly random
    ``k``-subset for i.i.d. continuous ``u``)."""
    xp = shim.namespace(u)
    return xp.argsort(u)[:k]


def ensemble_members(ensemble: Any, members: Any) -> Any:
    """The sub-ensemble of ``members`` ``[k]`` (``subset_indices``) of an ensemble whose leaves stack their members
    on the leading axis (``[E, ...]`` -> ``[k, ...]``): the target evaluates only the ``k`` it takes the min of."""
    return shim.tree_map(lambda leaf: leaf[members], ensemble)


def ensemble_critic_loss(q: Any, target: Any) -> Any:
    """``mean_{e,b} (Q_e(b) - y(b))^2`` for ``q`` ``[E, B]`` and the target ``y`` ``[B]`` (gradient stopped)."""
    xp = shim.namespace(q, target)
    return xp.mean(xp.square(q - xp.stop_gradient(target)[None, :]))


def symmetric_split(batch_size: int, prior_fraction: float = 0.5) -> tuple[int, int]:
    """Rows of a minibatch from (online, prior) data: ``round(prior_fraction * batch_size)`` prior."""
    if not 0.0 <= prior_fraction <= 1.0:
        raise ValueError(f"prior_fraction must be in [0, 1], got {prior_fraction}")
    prior = round(prior_fraction * batch_size)
    return batch_size - prior, prior


def compose(online: Mapping[str, Any], prior: Mapping[str, Any]) -> dict[str, Any]:
    """Minibatches ``[U, n_online + n_prior, ...]``: each of the U rows the online ``[U, n_online, ...]``
    samples first, then the prior ``[U, n_prior, ...]`` ones (fields of ``online``)."""
    out = {}
    for name, a in online.items():
        xp = shim.namespace(a)
        out[name] = xp.concat([a, prior[name]], axis=1)
    return out
