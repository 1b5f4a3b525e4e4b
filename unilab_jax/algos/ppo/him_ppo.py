"""HIM-PPO (Long et al., arXiv 2312.11460, "Hybrid Internal Model"): PPO with a history encoder.

Lock-step PPO on trajectory slots, on a ``<task>_hist`` task variant (``tasks/history.py``,
``history_extrinsics=False``) whose observation is the last ``H`` frames. A history encoder (MLP)
outputs a velocity estimate ``v_hat`` and a unit-norm latent ``l``; the policy sees
``[current frame, v_hat, l]`` with gradients stopped at the estimator (the policy gradient does not
shape it). The estimator is trained in the same jitted update, on the same minibatches, with its own
Adam (HIMLoco: lr 1e-3, gradient clip 10) on

    velocity_coef * mean((v_hat - v)^2) + swap_coef * swapped_prediction(l, l_target, prototypes)

where ``v`` are the ``velocity_cols`` of the *successor's* privileged critic observation and
``l_target`` a target encoder's unit latent of that whole (normalised) successor critic observation,
as in HIMLoco's estimator: the history must predict what the next privileged state will be. Prototype
codes are Sinkhorn-balanced (``core.him``); prototypes are re-projected to unit norm after each
step. For Go1 (``go1_joystick_flat``'s 123-dim critic observation) the clean body-frame linear
velocity is critic columns 57, 58, 59, and the recipe removes the measured velocity (actor columns
0-2) from the frames, so the estimate is not a copy of an input.

Published weights: ``{"actor", "log_std", "estimator": {"encoder", "prototypes"}, "obs_norm"}``
(the prototypes only give the latent size to ``act``). JAX learner only.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.algos.ppo import ppo
from unilab_jax.algos.ppo.ppo import PPOConfig, extras
from unilab_jax.core import him, normalizer
from unilab_jax.lazy import learner_maker

SYNC = "lockstep"
BUFFER = "trajectory"
PLATFORMS = ("jax",)
POLICY_KEYS = ("actor", "critic", "log_std")

__all__ = ["SYNC", "BUFFER", "Config", "act", "extras", "make_learner", "check_run", "check_spec"]


@dataclasses.dataclass(frozen=True)
class HIMPPOConfig(PPOConfig):
    """PPO's hyperparameters plus the estimator's (HIMLoco's defaults)."""

    velocity_cols: tuple[int, ...] = ()  # critic-observation columns of the velocity target (required)
    estimator_hidden: tuple[int, ...] = (128, 64)
    target_hidden: tuple[int, ...] = (128, 64)
    latent_dim: int = 16
    num_prototypes: int = 32
    temperature: float = 3.0
    sinkhorn_iters: int = 3
    sinkhorn_eps: float = 0.05
    estimator_learning_rate: float = 1e-3
    estimator_max_grad_norm: float = 10.0
    velocity_coef: float = 1.0
    swap_coef: float = 1.0


Config = HIMPPOConfig
make_learner = learner_maker(__name__)


def init_params(key: Any, spec: Any, config: HIMPPOConfig, xp: shim.Backend) -> dict[str, Any]:
    """PPO's actor (input ``d + V + L``), critic and log_std, plus ``estimator``: ``encoder`` (H d ->
    V + L), ``target`` (critic obs -> L) and unit-norm ``prototypes`` [K, L]."""
    k_ppo, k_enc, k_tgt, k_proto = xp.random.split(key, 4)
    v, lat = len(config.velocity_cols), config.latent_dim
    params = ppo.init_params(k_ppo, spec.frame_dim + v + lat, spec.critic_obs_dim, spec.action_dim, config, xp)
    params["estimator"] = {
        "encoder": nets.init(k_enc, [spec.obs_dim, *config.estimator_hidden, v + lat], xp),
        "target": nets.init(k_tgt, [spec.critic_obs_dim, *config.target_hidden, lat], xp),
        "prototypes": him.l2_normalize(xp.random.normal(k_proto, (config.num_prototypes, lat))),
    }
    return params


def estimate(estimator: dict, x_normed: Any) -> tuple[Any, Any]:
    """History encoder: normalised obs [..., H d] -> (v_hat [..., V], unit latent [..., L])."""
    out = nets.apply(estimator["encoder"], x_normed)
    lat = int(estimator["prototypes"].shape[1])
    v = int(out.shape[-1]) - lat
    return out[..., :v], him.l2_normalize(out[..., v:])


def actor(params: dict, obs_norm: Any, obs: Any) -> tuple[Any, Any]:
    """PPO actor (``ppo.Actor``): obs [..., H d] -> (mean, log_std) [..., A]; the estimator's outputs
    enter with stopped gradients."""
    xp = shim.namespace(obs)
    x = normalizer.normalize(obs_norm, obs)
    v_hat, lat = estimate(params["estimator"], x)
    d = int(params["actor"][0]["w"].shape[0]) - int(v_hat.shape[-1]) - int(lat.shape[-1])
    n = int(obs.shape[-1])
    inp = xp.concat([x[..., n - d:], xp.stop_gradient(v_hat), xp.stop_gradient(lat)], axis=-1)
    mean = nets.apply(params["actor"], inp)
    return mean, xp.broadcast_to(params["log_std"], mean.shape)


def estimator_loss(estimator: dict, obs_norm: Any, critic_norm: Any, mb: dict,
                   config: HIMPPOConfig) -> tuple[Any, dict[str, Any]]:
    """The estimator's loss on a flat minibatch: ``mb["obs"]`` [N, H d], ``mb["next_critic_obs"]`` [N, C]."""
    xp = shim.namespace(mb["obs"])
    v_hat, z_source = estimate(estimator, normalizer.normalize(obs_norm, mb["obs"]))
    nxt = mb["next_critic_obs"]
    z_target = him.l2_normalize(nets.apply(estimator["target"], normalizer.normalize(critic_norm, nxt)))
    v_target = xp.stack([nxt[..., c] for c in config.velocity_cols], axis=-1)
    vel = him.velocity_loss(v_hat, v_target)
    swap, metrics = him.swapped_prediction_loss(z_source, z_target, him.l2_normalize(estimator["prototypes"]),
                                                config.temperature, config.sinkhorn_iters, config.sinkhorn_eps)
    total = config.velocity_coef * vel + config.swap_coef * swap
    metrics = {**metrics, "velocity_loss": xp.stop_gradient(vel),
               "velocity_target_var": xp.mean(xp.var(v_target, axis=0))}
    return total, metrics


def policy_weights(params: dict, obs_norm: Any) -> dict[str, Any]:
    est = params["estimator"]
    return {"actor": params["actor"], "log_std": params["log_std"],
            "estimator": {"encoder": est["encoder"], "prototypes": est["prototypes"]}, "obs_norm": obs_norm}


def act(weights: dict[str, Any], obs: Any, noise: Any, deterministic: bool = False) -> tuple[Any, dict]:
    """Gaussian policy on [frame, v_hat, latent]. obs [M, H d], noise [M, A] -> action [M, A], PPO's extras."""
    return ppo.gaussian_act(actor, weights, obs, noise, deterministic)


def check_run(platform: str, task_config: Any, config: HIMPPOConfig) -> None:
    """Flag checks before anything starts (``cli.build_run``): ValueError with the reason."""
    if platform not in PLATFORMS:
        raise ValueError(f"him_ppo has a learner for --platform={'/'.join(PLATFORMS)} only, not {platform!r}")
    if not hasattr(task_config, "history_len") or task_config.history_extrinsics:
        raise ValueError("him_ppo needs a '<task>_hist' task variant (tasks/history.py) with history_extrinsics=False")
    if not config.velocity_cols:
        raise ValueError("him_ppo needs velocity_cols: the critic-observation columns of the velocity to estimate")


def check_spec(spec: Any, config: HIMPPOConfig) -> None:
    if not hasattr(spec, "history_len") or spec.extrinsics_in_obs:
        raise ValueError(f"him_ppo needs a '<task>_hist' task with history_extrinsics=False, got {spec.name!r}")
    bad = [c for c in config.velocity_cols if not 0 <= c < spec.critic_obs_dim]
    if not config.velocity_cols or bad:
        raise ValueError(f"velocity_cols {config.velocity_cols} must be non-empty columns of the "
                         f"{spec.critic_obs_dim}-dim critic observation")
