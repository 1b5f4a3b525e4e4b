"""JAX learner of HIM-PPO: ``ppo_jax.Learner``'s update with the estimator trained alongside.

One jitted update: every minibatch step takes the gradient of PPO's loss plus the estimator's loss
(the policy consumes the estimator's outputs through ``stop_gradient``, so each part of the sum
only reaches its own parameters), then applies PPO's optimizer (KL-adaptive learning rate) to the
actor/critic/log_std and a separate Adam to the estimator.
"""

from __future__ import annotations

from typing import Any

import jax
import optax

from unilab_jax import xp as shim
from unilab_jax.algos.ppo import him_ppo, ppo
from unilab_jax.algos.ppo import learner_jax as ppo_jax
from unilab_jax.core import him

XP = shim.get("jax")


def _policy_part(tree: dict) -> dict:
    return {k: tree[k] for k in him_ppo.POLICY_KEYS}


def make_learner(algo: Any, config: him_ppo.HIMPPOConfig, spec: Any) -> HIMLearner:
    """The registry's factory for HIM-PPO (after its spec check)."""
    algo.check_spec(spec, config)
    return HIMLearner(config, spec)


class HIMLearner(ppo_jax.Learner):
    extra_fields = ("next_critic_obs",)
    actor = staticmethod(him_ppo.actor)

    def __init__(self, config: him_ppo.HIMPPOConfig, spec: Any):
        self.est_tx = optax.chain(optax.clip_by_global_norm(config.estimator_max_grad_norm),
                                  optax.adam(config.estimator_learning_rate))
        super().__init__(config, spec, use_vtrace=False)

    def init_params(self, key: jax.Array) -> dict:
        return him_ppo.init_params(key, self.spec, self.config, XP)

    def init_opt_state(self, params: dict) -> dict:
        return {"policy": self.tx.init(_policy_part(params)), "estimator": self.est_tx.init(params["estimator"])}

    def loss(self, params: dict, obs_norm: Any, critic_norm: Any, mb: dict) -> tuple[jax.Array, dict]:
        ppo_total, metrics = ppo.loss(params, obs_norm, critic_norm, mb, self.config, actor=self.actor)
        est_total, est_metrics = him_ppo.estimator_loss(params["estimator"], obs_norm, critic_norm, mb, self.config)
        return ppo_total + est_total, {**metrics, **est_metrics}

    def apply_gradients(self, params: dict, opt_state: dict, grads: dict, metrics: dict,
                        fraction: jax.Array) -> tuple[dict, dict, Any]:
        policy, policy_state, lr = super().apply_gradients(_policy_part(params), opt_state["policy"],
                                                           _policy_part(grads), metrics, fraction)
        updates, est_state = self.est_tx.update(grads["estimator"], opt_state["estimator"], params["estimator"])
        est = optax.apply_updates(params["estimator"], updates)
        est = {**est, "prototypes": him.l2_normalize(est["prototypes"])}
        return {**policy, "estimator": est}, {"policy": policy_state, "estimator": est_state}, lr

    @staticmethod
    def weights(state: ppo.TrainState) -> dict:
        return him_ppo.policy_weights(state.params, state.obs_norm)
