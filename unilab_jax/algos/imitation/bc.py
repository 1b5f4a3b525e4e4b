"""Behaviour cloning: a deterministic MLP policy regressed onto an operator's actions.

The policy is ``tanh(mlp(normalize(obs)))`` (actions in (-1, 1) like every task's), its loss the mean
squared error to the operator's actions summed over action dimensions. Input normalisation uses the
dataset's statistics (``core.normalizer``, with a variance floor), fixed for a fit. HG-DAgger
(``unilab_jax/training/hgdagger.py``) fits it on the aggregated operator data; the robot tasks' operators act in
the task layer, so the policy only ever sees observations.

Weights: ``{"actor": mlp, "obs_norm": RunningStats}`` (the shape of SAC's, so ``act`` runs in workers and
evaluations alike). An ensemble (``BCConfig.ensemble`` > 1, HG-DAgger's novice as in Kelly et al. 2019) is
``{"actors": [mlp, ...], "obs_norm": RunningStats}``: members fitted from different seeds on the same data
(one input normalisation), the policy their mean action. One network's success on pick-and-place swings
with its fit's seed (24 demonstrations, six seeds: 0.38-0.74 over 80 episodes); the mean of five does not
(0.79, 0.84).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.core import normalizer

ACTIVATION = "relu"
# Variance floor of the input normalisation: demonstrations barely vary some inputs (the tcp's orientation),
# and a novice's small deviation there must not read as tens of standard deviations.
VAR_FLOOR = 1e-3


@dataclasses.dataclass(frozen=True)
class BCConfig:
    """Network and fit: ``epochs`` passes over the dataset in minibatches of ``batch_size`` (AdamW), or, with
    ``steps``, a fixed budget of gradient steps whatever the dataset's size (whole epochs, at least ``steps``)."""

    hidden: tuple[int, ...] = (256, 256)
    learning_rate: float = 1e-3
    weight_decay: float = 1.0  # decoupled (AdamW), per step: params *= 1 - learning_rate * weight_decay
    batch_size: int = 256
    epochs: int = 50
    steps: int | None = None  # gradient steps per fit (replaces epochs; None: epochs decide)
    ensemble: int = 1  # networks fitted from different seeds, the policy their mean action (1: one network)

    def __post_init__(self):
        if self.batch_size < 1 or self.epochs < 1 or not self.learning_rate > 0 or self.weight_decay < 0:
            raise ValueError(f"BCConfig: batch_size and epochs must be positive, learning_rate > 0 and "
                             f"weight_decay >= 0, got {self}")
        if self.steps is not None and self.steps < 1:
            raise ValueError(f"BCConfig: steps must be positive (or None), got {self.steps}")
        if self.ensemble < 1:
            raise ValueError(f"BCConfig: ensemble must be >= 1, got {self.ensemble}")


def init_params(key: Any, obs_dim: int, action_dim: int, config: BCConfig, xp: shim.Backend) -> list[dict]:
    """The policy MLP ``[obs_dim, *hidden, action_dim]``."""
    return nets.init(key, [obs_dim, *config.hidden, action_dim], xp)


def policy(actor: list[dict], obs_norm: normalizer.RunningStats, obs: Any) -> Any:
    """obs [B, D] -> action [B, A] in (-1, 1)."""
    xp = shim.namespace(obs)
    return xp.tanh(nets.apply(actor, normalizer.normalize(obs_norm, obs, eps=VAR_FLOOR), ACTIVATION))


def loss(actor: list[dict], obs_norm: normalizer.RunningStats, obs: Any, action: Any) -> Any:
    """``mean_B sum_A (policy(obs) - action)^2`` (scalar); ``action`` [B, A] the operator's."""
    xp = shim.namespace(obs)
    return xp.mean(xp.sum(xp.square(policy(actor, obs_norm, obs) - action), axis=-1))


def act(weights: dict, obs: Any, noise: Any, deterministic: bool = False) -> tuple[Any, dict]:
    """The deterministic policy (``noise`` unread; an ensemble's mean action): obs [M, D] -> (action [M, A], {})."""
    xp = shim.namespace(obs)
    actors = weights["actors"] if "actors" in weights else [weights["actor"]]
    mean = sum(policy(actor, weights["obs_norm"], obs) for actor in actors) / len(actors)
    return xp.astype(mean, xp.float32), {}
