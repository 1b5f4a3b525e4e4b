"""What every off-policy declaration of this folder shares (SAC, TD3, FastSAC, FlashSAC, RLPD, SAC Flow): the
hidden activation, the normalisation bundle the losses read (``Norms``), stacked ensembles of MLPs, the critic's
input and the discounts of a minibatch. ``sac.py`` re-exports them (``sac.Norms`` ...).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.core import normalizer

ACTIVATION = "relu"  # hidden activation of actor and critics (the workers' ``act`` must agree)


class Norms(NamedTuple):
    """Input/reward normalisation used by the losses.

    ``obs``/``critic`` are RunningStats over ``obs`` [D] and ``critic_obs`` [Dc]; ``reward_scale`` is
    a scalar the rewards are divided by before the critic target (1.0: no reward normalisation).
    """

    obs: normalizer.RunningStats
    critic: normalizer.RunningStats
    reward_scale: Any


def mlp_apply(params: list[dict], x: Any) -> Any:
    """``nets.apply`` with this family's activation; ensemble params give ``[E, B, out]``."""
    return nets.apply(params, x, ACTIVATION)


def ensemble_init(key: Any, sizes: list[int], n: int, xp: shim.Backend, final_scale: float = 1.0,
                  layer_norm: bool = False) -> list[dict]:
    """``n`` independent MLPs stacked leaf-wise: weights ``[n, in, out]``, vectors ``[n, 1, out]``.

    ``nets.apply(params, x [B, in])`` then returns ``[n, B, out]`` (broadcast matmul).
    """
    keys = xp.random.split(key, n)
    members = [nets.init(keys[i], sizes, xp, final_scale=final_scale, layer_norm=layer_norm) for i in range(n)]

    def stack(*leaves: Any) -> Any:
        s = xp.stack(list(leaves))
        return xp.reshape(s, (n, 1, s.shape[-1])) if len(leaves[0].shape) == 1 else s

    return shim.tree_map(stack, *members)


def critic_input(critic_norm: normalizer.RunningStats, critic_obs: Any, action: Any) -> Any:
    """``concat(normalize(critic_obs), action)``: [B, Dc], [B, A] -> [B, Dc + A]."""
    xp = shim.namespace(critic_obs, action)
    return xp.concat([normalizer.normalize(critic_norm, critic_obs), action], axis=-1)


def discounts(mb: dict, gamma: float) -> Any:
    """``gamma * (1 - terminated)`` [B]: termination cuts the bootstrap, truncation does not."""
    xp = shim.namespace(mb["terminated"])
    return gamma * (1.0 - xp.astype(mb["terminated"], xp.float32))


def scalar_q(critic: Any, x: Any, critic_apply: Callable = mlp_apply) -> Any:
    """Twin scalar critics on ``x`` [B, Dc + A] -> Q [E, B]."""
    return critic_apply(critic, x)[..., 0]
