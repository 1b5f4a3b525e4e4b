"""Image observations for the SAC family (SAC, RLPD, SAC Flow): DrQ's encoder sharing, around unchanged losses.

A task with images declares ``spec.image_shape == (H, W, C)`` (uint8, channels last, C = 3 x cameras x stacked
frames) and its replay batches carry ``image`` and ``next_image`` (uint8 ``[U, B, H, W, C]``, the successor's
image before auto-reset, like ``next_obs``). Then (Kostrikov et al., DrQ, arXiv:2004.13649):

* One convolutional encoder (``core.pixels``; ``encoder_channels``, ``encoder_strides``, ``feature_dim``)
  lives in the critic's parameters: ``critic = {"net": the algorithm's critic, "encoder": encoder}``, so the
  critic loss's gradient trains it, the critic optimizer moves it and Polyak averaging gives the target
  critic a target encoder.
* Each gradient step shifts ``image`` and ``next_image`` independently (``core.pixels.random_shift``, offsets
  in ``[-image_pad, image_pad]`` drawn from a key of the step's split), then the algorithm's own losses run
  on widened observations: ``critic_obs ++ features(image)`` for the critic (gradient reaching the encoder),
  ``obs ++ stop_gradient(features(image))`` for the actor (the actor loss never trains the encoder; its
  features come from the freshly updated encoder), and ``next_obs ++ f'``, ``next_critic_obs ++ f'`` with
  ``f'`` the target encoder's features of ``next_image`` (gradient-stopped) for the soft target.
* ``actor_encoder`` (an asymmetric actor-critic whose critic also reads privileged state, e.g. the robot tasks'
  ``critic_state``): the actor gets an encoder of its own, ``actor = {"net": the algorithm's actor, "encoder":
  encoder}``, trained by the actor loss (its gradient through Q's action reaches it), and reads
  ``obs ++ features_actor(image)``; the soft target's next action reads ``next_obs ++ features_actor(next_image)``
  (gradient-stopped). The critic's encoder, trained by the critic, serves the critic only: a critic that knows the
  object poses needs no image features that locate them, so what its shared features tell the actor would be a
  by-product of the critic's fit.
* The normalizers keep running over ``obs`` / ``critic_obs`` only; the features (bounded by tanh) pass
  through them unscaled (``widen_stats``: mean 0, variance 1).
* Published weights add ``encoder`` (the actor's with ``actor_encoder``, else the critic's) and
  ``encoder_strides`` (int32); ``act(..., image=)`` encodes the worker's images with them (numpy in the rollout
  workers, ``xp.conv2d``'s im2col).
"""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType
from typing import Any

from unilab_jax import xp as shim
from unilab_jax.algos import contract
from unilab_jax.core import normalizer, pixels

SHIFT = "image_shift"  # a minibatch's DrQ offsets [2, B, 2] (image, next_image), put there by the learners


def image_shape(spec: Any) -> tuple[int, ...]:
    """``spec.image_shape`` as a tuple: ``(H, W, C)`` for a task with images, ``()`` without."""
    return tuple(int(n) for n in (getattr(spec, "image_shape", ()) or ()))


def check_config(cfg: Any) -> list[str]:
    """The encoder fields' problems (empty when valid)."""
    problems = []
    if not cfg.encoder_channels or len(cfg.encoder_channels) != len(cfg.encoder_strides):
        problems.append(f"encoder_channels and encoder_strides need one entry per convolution (got "
                        f"{cfg.encoder_channels}, {cfg.encoder_strides})")
    if any(c < 1 for c in cfg.encoder_channels) or any(s < 1 for s in cfg.encoder_strides):
        problems.append("encoder_channels and encoder_strides must be positive")
    if cfg.feature_dim < 1 or cfg.image_pad < 0:
        problems.append(f"need feature_dim >= 1 and image_pad >= 0 (got {cfg.feature_dim}, {cfg.image_pad})")
    return problems


def check_algo(algo: ModuleType, spec: Any, config: Any) -> None:
    """Raises a clear error when ``algo`` (with ``config``) cannot learn from the images ``spec`` declares."""
    shape = image_shape(spec)
    if not shape:
        return
    name = algo.__name__.rsplit(".", 1)[-1]
    if not contract.hooks(algo).images:
        raise ValueError(f"{name} does not learn from images, but task {spec.name!r} has image_shape {shape}; "
                         f"use sac, rlpd, sacflow or rlpd_flow")
    if len(shape) != 3:
        raise ValueError(f"task {spec.name!r}: image_shape must be (H, W, C), got {shape}")
    pixels.flat_dim(shape, config.encoder_channels, config.encoder_strides)


def init_params(algo: ModuleType, shape: tuple[int, ...], key: Any, obs_dim: int, critic_obs_dim: int,
                action_dim: int, config: Any, xp: shim.Backend) -> dict[str, Any]:
    """The algorithm's networks on inputs widened by ``feature_dim``, the encoder beside the critic (and, with
    ``actor_encoder``, another beside the actor)."""
    k_net, k_enc, k_actor = xp.random.split(key, 3)
    f = config.feature_dim
    params = algo.init_params(k_net, obs_dim + f, critic_obs_dim + f, action_dim, config, xp)
    encoder = pixels.encoder_init(k_enc, shape, config.encoder_channels, config.encoder_strides, f, xp)
    params["critic"] = {"net": params["critic"], "encoder": encoder}
    if config.actor_encoder:
        own = pixels.encoder_init(k_actor, shape, config.encoder_channels, config.encoder_strides, f, xp)
        params["actor"] = {"net": params["actor"], "encoder": own}
    return params


def widen_stats(stats: normalizer.RunningStats, n: int) -> normalizer.RunningStats:
    """``stats`` over ``[D]`` followed by ``n`` pass-through entries (mean 0, variance 1)."""
    xp = shim.namespace(stats.mean)
    return normalizer.RunningStats(xp.concat([stats.mean, xp.zeros((n,), dtype=xp.float32)]),
                                   xp.concat([stats.var, xp.ones((n,), dtype=xp.float32)]), stats.count)


def _widen(norms: Any, mb: dict, feats: dict[str, Any]) -> tuple[Any, dict]:
    """Norms and minibatch with ``feats[k]`` appended to ``mb[k]`` (``k`` among obs, critic_obs, next_obs,
    next_critic_obs; all features of one width)."""
    xp = shim.namespace(*feats.values())
    n = int(next(iter(feats.values())).shape[-1])
    mb = {**mb, **{k: xp.concat([mb[k], f], axis=-1) for k, f in feats.items()}}
    return norms._replace(obs=widen_stats(norms.obs, n), critic=widen_stats(norms.critic, n)), mb


def _actor_parts(actor: Any, config: Any) -> tuple[Any, Any]:
    """(the algorithm's actor, the actor's own encoder or None)."""
    return (actor["net"], actor["encoder"]) if config.actor_encoder else (actor, None)


def critic_loss(algo: ModuleType) -> Callable:
    """``algo.critic_loss`` with the encoder in the critic (same signature)."""

    def loss(critic: dict, target_critic: dict, actor: Any, log_alpha: Any, norms: Any, mb: dict, noise: Any,
             config: Any) -> tuple[Any, dict]:
        xp = shim.namespace(log_alpha)
        strides = config.encoder_strides
        feat = pixels.encode(critic["encoder"], mb["image"], strides)
        next_feat = xp.stop_gradient(pixels.encode(target_critic["encoder"], mb["next_image"], strides))
        actor, own = _actor_parts(actor, config)
        next_actor_feat = next_feat if own is None else xp.stop_gradient(pixels.encode(own, mb["next_image"], strides))
        norms, mb = _widen(norms, mb, {"critic_obs": feat, "next_obs": next_actor_feat, "next_critic_obs": next_feat})
        return algo.critic_loss(critic["net"], target_critic["net"], actor, log_alpha, norms, mb, noise, config)

    return loss


def actor_loss(algo: ModuleType) -> Callable:
    """``algo.actor_loss`` on features of the image (same signature): gradient-stopped ones of the (updated)
    critic's encoder, or with ``actor_encoder`` the actor's own (trained by this loss) for the actor's input."""

    def loss(actor: Any, critic: dict, log_alpha: Any, norms: Any, mb: dict, eps: Any, config: Any) -> tuple:
        xp = shim.namespace(log_alpha)
        strides = config.encoder_strides
        feat = xp.stop_gradient(pixels.encode(critic["encoder"], mb["image"], strides))
        actor, own = _actor_parts(actor, config)
        norms, mb = _widen(norms, mb, {"obs": feat if own is None else pixels.encode(own, mb["image"], strides),
                                       "critic_obs": feat})
        return algo.actor_loss(actor, critic["net"], log_alpha, norms, mb, eps, config)

    return loss


def augment(mb: dict, pad: int) -> dict:
    """``mb`` with ``image`` / ``next_image`` shifted by the offsets ``mb[SHIFT]`` [2, B, 2] (removed)."""
    mb = dict(mb)
    shifts = mb.pop(SHIFT)
    mb["image"] = pixels.random_shift(mb["image"], shifts[0], pad)
    mb["next_image"] = pixels.random_shift(mb["next_image"], shifts[1], pad)
    return mb


def shift_shape(batch_size: int) -> tuple[int, int, int]:
    """Shape of a gradient step's DrQ offsets: (image / next_image, B, row / column)."""
    return (2, batch_size, 2)


def add_encoder(weights: dict, actor: Any, critic: dict, config: Any) -> dict:
    """Published weights (``weights["actor"]`` the algorithm's actor) with the encoder the actor reads and its
    strides (what ``actor_inputs`` reads): the actor's own with ``actor_encoder``, else the critic's."""
    actor, own = _actor_parts(actor, config)
    encoder = critic["encoder"] if own is None else own
    xp = shim.namespace(encoder["linear"]["w"])
    return {**weights, "actor": actor, "encoder": encoder,
            "encoder_strides": xp.asarray(list(config.encoder_strides), dtype=xp.int32)}


def actor_inputs(weights: dict, obs: Any, image: Any) -> tuple[dict, Any]:
    """The worker side: ``(weights, obs ++ features(image))`` with the widened observation normalizer, or
    ``(weights, obs)`` unchanged without images. image: uint8 ``[M, H, W, C]``; obs: ``[M, D]``."""
    if "encoder" not in weights:
        if image is not None:
            raise ValueError("act got image= but these weights have no encoder (the task declares no image_shape)")
        return weights, obs
    if image is None:
        raise ValueError("these weights encode images: act needs image= (uint8 [M, H, W, C])")
    xp = shim.namespace(obs)
    strides = [int(s) for s in shim.namespace(weights["encoder_strides"]).asnumpy(weights["encoder_strides"])]
    image = image if shim.namespace(image) is xp else xp.from_numpy(shim.namespace(image).asnumpy(image))
    feat = pixels.encode(weights["encoder"], image, strides)
    n = int(feat.shape[-1])
    return ({**weights, "obs_norm": widen_stats(weights["obs_norm"], n)},
            xp.concat([obs, xp.astype(feat, xp.float32)], axis=-1))
