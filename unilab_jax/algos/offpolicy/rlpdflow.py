"""RLPD Flow: RLPD (``rlpd.py``) with SAC Flow's actor (``sacflow.py``), to compare the two actors on equal terms.

Everything but the policy is RLPD's: symmetric sampling of prior data (``prior_dir``, ``prior_fraction``), the
``num_critics`` LayerNorm ensemble, the soft target's minimum over a random subset of ``subset_size`` target
members (``rlpd.critic_target``), the actor against the ensemble's mean Q, ``actor_every`` and the update order of
the SAC-family learners. The policy is SAC Flow's gated K-step flow (``flow_steps``, ``gate_bias``): the next
action of the soft target and the actor's action are drawn through its chain (``sacflow.sample``), and the chain's
log-probability is the entropy term of the target, the actor and the temperature, whose target per action
dimension defaults to SAC Flow's 0 (``sacflow.py`` says why), not RLPD's -0.5.

The learners draw ``(flow_steps + 1) |A|`` normals per sample (``learner_noise_dim``) and RLPD's uniform
``[num_critics]`` per gradient step (``critic_noise_shape``). Published weights, ``act`` and the workers' noise are
SAC Flow's.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from unilab_jax import xp as shim
from unilab_jax.algos.offpolicy import rlpd, sacflow
from unilab_jax.algos.offpolicy.rlpd import RLPDConfig, actor_every, critic_noise_shape
from unilab_jax.algos.offpolicy.sac import Norms, extras, temperature_loss
from unilab_jax.algos.offpolicy.sacflow import SACFlowConfig, act, learner_noise_dim, noise_dim
from unilab_jax.lazy import learner_maker

SYNC = "async"
BUFFER = "replay"
IMAGES = True  # learns from image observations (``image_obs``)
PRIOR_DATA = True  # Config.prior_dir / prior_fraction: the trainer mixes prior data into every minibatch

__all__ = ["SYNC", "BUFFER", "IMAGES", "PRIOR_DATA", "Config", "RLPDFlowConfig", "extras", "act", "make_learner",
           "noise_dim", "learner_noise_dim", "critic_noise_shape", "actor_every", "init_params", "critic_loss",
           "actor_loss", "temperature_loss"]


@dataclasses.dataclass(frozen=True)
class RLPDFlowConfig(RLPDConfig, SACFlowConfig):
    """RLPD's fields and defaults plus SAC Flow's (``flow_steps``, ``gate_bias``) and its entropy target (0 per
    action dimension); each base checks its own fields."""

    target_entropy_per_dim: float = 0.0


Config = RLPDFlowConfig
make_learner = learner_maker(__name__)


def init_params(key: Any, obs_dim: int, critic_obs_dim: int, action_dim: int, config: RLPDFlowConfig,
                xp: shim.Backend) -> dict[str, Any]:
    """``{"actor": SAC Flow's {"velocity", "log_std"}, "critic": RLPD's LayerNorm num_critics-ensemble}``."""
    kv, ks, kc = xp.random.split(key, 3)
    return {"actor": sacflow.actor_init(kv, ks, obs_dim, action_dim, config, xp),
            "critic": rlpd.critic_init(kc, critic_obs_dim, action_dim, config, xp)}


def critic_loss(critic: Any, target_critic: Any, actor: Any, log_alpha: Any, norms: Norms, mb: dict,
                noise: tuple[Any, Any], config: RLPDFlowConfig) -> tuple[Any, dict]:
    """RLPD's ensemble MSE to the subset-min soft target, ``a'`` and its log-probability from the flow;
    ``noise = (eps_next [B, (K + 1) A], u [num_critics])``."""
    return rlpd.critic_loss(critic, target_critic, actor, log_alpha, norms, mb, noise, config, sacflow.sample)


def actor_loss(actor: Any, critic: Any, log_alpha: Any, norms: Norms, mb: dict, eps: Any,
               config: RLPDFlowConfig) -> tuple[Any, tuple]:
    """SAC Flow's actor loss against the ensemble's mean Q (RLPD's); eps [B, (K + 1) A]."""
    return sacflow.actor_loss(actor, critic, log_alpha, norms, mb, eps, config, use_min=False)
