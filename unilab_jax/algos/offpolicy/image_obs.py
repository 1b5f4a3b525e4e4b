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
* The normalizers keep running over ``obs`` / ``critic_obs`` only; the features (bounded by tanh) pass
  through them unscaled (``widen_stats``: mean 0, variance 1).
* Published weights add ``encoder`` and ``encoder_strides`` (int32); ``act(..., image=)`` encodes the
  worker's images with them (numpy in the rollout workers, ``xp.conv2d``'s im2col).
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
                         f"use sac, rlpd or sacflow")
    if len(shape) != 3:
        raise ValueError(f"task {spec.name!r}: image_shape must be (H, W, C), got {shape}")
    pixels.flat_dim(shape, config.encoder_channels, config.encoder_strides)


def init_params(algo: ModuleType, shape: tuple[int, ...], key: Any, obs_dim: int, critic_obs_dim: int,
                action_dim: int, config: Any, xp: shim.Backend) -> dict[str, Any]:
    """The algorithm's networks on inputs widened by ``feature_dim``, the encoder beside the critic."""
    k_net, k_enc = xp.random.split(key, 2)
    f = config.feature_dim
    params = algo.init_params(k_net, obs_dim + f, critic_obs_dim + f, action_dim, config, xp)
    encoder = pixels.encoder_init(k_enc, shape, config.encoder_channels, config.encoder_strides, f, xp)
    params["critic"] = {"net": params["critic"], "encoder": encoder}
    return params


def widen_stats(stats: normalizer.RunningStats, n: int) -> normalizer.RunningStats:
    """``stats`` over ``[D]`` followed by ``n`` pass-through entries (mean 0, variance 1)."""
    xp = shim.namespace(stats.mean)
    return normalizer.RunningStats(xp.concat([stats.mean, xp.zeros((n,), dtype=xp.float32)]),
                                   xp.concat([stats.var, xp.ones((n,), dtype=xp.float32)]), stats.count)


def _widen(norms: Any, mb: dict, feat: Any, next_feat: Any = None) -> tuple[Any, dict]:
    """Norms and minibatch of the widened observations (``next_*`` only when ``next_feat`` is given)."""
    xp = shim.namespace(feat)
    n = int(feat.shape[-1])
    cat = lambda a, f: xp.concat([a, f], axis=-1)  # noqa: E731
    fixed = xp.stop_gradient(feat)
    mb = {**mb, "obs": cat(mb["obs"], fixed), "critic_obs": cat(mb["critic_obs"], feat)}
    if next_feat is not None:
        mb.update(next_obs=cat(mb["next_obs"], next_feat), next_critic_obs=cat(mb["next_critic_obs"], next_feat))
    return norms._replace(obs=widen_stats(norms.obs, n), critic=widen_stats(norms.critic, n)), mb


def critic_loss(algo: ModuleType) -> Callable:
    """``algo.critic_loss`` with the encoder in the critic (same signature)."""

    def loss(critic: dict, target_critic: dict, actor: Any, log_alpha: Any, norms: Any, mb: dict, noise: Any,
             config: Any) -> tuple[Any, dict]:
        xp = shim.namespace(log_alpha)
        strides = config.encoder_strides
        feat = pixels.encode(critic["encoder"], mb["image"], strides)
        next_feat = xp.stop_gradient(pixels.encode(target_critic["encoder"], mb["next_image"], strides))
        norms, mb = _widen(norms, mb, feat, next_feat)
        return algo.critic_loss(critic["net"], target_critic["net"], actor, log_alpha, norms, mb, noise, config)

    return loss


def actor_loss(algo: ModuleType) -> Callable:
    """``algo.actor_loss`` on gradient-stopped features of the (updated) critic's encoder (same signature)."""

    def loss(actor: Any, critic: dict, log_alpha: Any, norms: Any, mb: dict, eps: Any, config: Any) -> tuple:
        xp = shim.namespace(log_alpha)
        feat = xp.stop_gradient(pixels.encode(critic["encoder"], mb["image"], config.encoder_strides))
        norms, mb = _widen(norms, mb, feat)
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


def add_encoder(weights: dict, critic: dict, config: Any) -> dict:
    """Published weights with the encoder and its strides (what ``actor_inputs`` reads)."""
    xp = shim.namespace(critic["encoder"]["linear"]["w"])
    return {**weights, "encoder": critic["encoder"],
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
