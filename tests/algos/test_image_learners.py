"""The SAC family on image observations (``image_obs``): config checks, which algorithms take images, where the
gradients go (critic -> encoder, actor -/-> encoder), one compile, the published weights and the worker's numpy
``act``, and an image-only contextual bandit learned end to end.

The image learner compiles at the default XLA optimisation level: at level 0 its convolutions run ~20x slower
on CPU (170 vs 9 ms per gradient step here), which costs more than the compile saves.
"""

from __future__ import annotations

import dataclasses
import types

import numpy as np
import pytest
from compile_options import FAST_COMPILE

jax = pytest.importorskip("jax")
jnp = jax.numpy

from tasks.base import TaskSpec  # noqa: E402
from unilab_jax import algos, nets  # noqa: E402
from unilab_jax.algos.offpolicy import image_obs, sac, sacflow  # noqa: E402
from unilab_jax.algos.offpolicy import learner_jax as offpolicy_jax  # noqa: E402
from unilab_jax.algos.offpolicy.sac import Norms  # noqa: E402
from unilab_jax.core import normalizer, pixels  # noqa: E402

H, OBS, A, B, U = 16, 3, 1, 64, 4


def image_spec(base: TaskSpec, shape: tuple[int, int, int]) -> types.SimpleNamespace:
    """``base`` with ``image_shape`` (the data path's TaskSpec field; a namespace works with or without it)."""
    return types.SimpleNamespace(**{**dataclasses.asdict(base), "image_shape": shape})


BASE = TaskSpec("img", OBS, OBS, A, 1, 0.02, ())
SPEC = image_spec(BASE, (H, H, 3))
CONFIG = sac.Config(actor_hidden=(64,), critic_hidden=(64,), batch_size=B, updates_per_call=U,
                    actor_learning_rate=1e-3, critic_learning_rate=1e-3, alpha_learning_rate=1e-3,
                    encoder_channels=(16, 16), encoder_strides=(2, 1), feature_dim=16, image_pad=2)
_LEARNER: list = []


def _learner() -> offpolicy_jax.SACFamilyLearner:
    # XLA's fast-compile options (tests/compile_options.py): the update compiles in about half the time; the bandit
    # below runs its 150 calls ~1.5 s slower and ends at the same error (this seed: 0.0144, 0.0146 with the defaults).
    if not _LEARNER:
        _LEARNER.append(offpolicy_jax.SACFamilyLearner(sac, CONFIG, SPEC, compiler_options=FAST_COMPILE))
    return _LEARNER[0]


def _grads(loss):
    """``loss``'s gradients in its two arguments, jitted with XLA's fast-compile options (tests/compile_options.py)."""
    return jax.jit(jax.grad(loss, argnums=(0, 1)), compiler_options=FAST_COMPILE)


def _images(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Dark noise with a bright 4x4 square in the left or the right half; the best action is +0.5 / -0.5."""
    side = rng.integers(0, 2, n)
    img = rng.integers(0, 40, (n, H, H, 3)).astype(np.uint8)
    rows, cols = rng.integers(2, H - 6, n), rng.integers(1, H // 2 - 5, n) + side * (H // 2)
    for i in range(n):
        img[i, rows[i]:rows[i] + 4, cols[i]:cols[i] + 4] = 220
    return img, np.where(side == 0, 0.5, -0.5).astype(np.float32)


def _batch(rng: np.random.Generator) -> dict:
    """A bandit batch: every transition terminal, reward -(a - best(image))^2, obs pure noise."""
    img, best = _images(rng, U * B)
    action = rng.uniform(-1, 1, (U * B, A)).astype(np.float32)
    reward = -np.sum((action - best[:, None]) ** 2, -1).astype(np.float32)
    obs = rng.normal(size=(U, B, OBS)).astype(np.float32)
    img = img.reshape(U, B, H, H, 3)
    return {"obs": obs, "critic_obs": obs, "action": action.reshape(U, B, A), "reward": reward.reshape(U, B),
            "next_obs": obs, "next_critic_obs": obs, "terminated": np.ones((U, B), bool),
            "truncated": np.zeros((U, B), bool), "image": img, "next_image": img}


def test_config_fields_are_validated():
    with pytest.raises(ValueError, match="one entry per convolution"):
        sac.Config(encoder_channels=(32, 32), encoder_strides=(2,))
    with pytest.raises(ValueError, match="positive"):
        sac.Config(encoder_strides=(2, 0, 1, 1))
    with pytest.raises(ValueError, match="feature_dim"):
        sac.Config(feature_dim=0)
    with pytest.raises(ValueError, match="image_pad"):
        algos.get("rlpd").Config(image_pad=-1)
    with pytest.raises(ValueError, match="too small"):
        offpolicy_jax.SACFamilyLearner(sac, sac.Config(), image_spec(BASE, (8, 8, 3)))


@pytest.mark.parametrize("name", ["fastsac", "flashsac", "td3"])
def test_other_algorithms_refuse_image_tasks(name):
    mod = algos.get(name)
    with pytest.raises(ValueError, match=f"{name} does not learn from images"):
        algos.make_learner(name, "jax", mod.Config(), SPEC)


def test_critic_gradient_trains_the_encoder_and_the_actor_gradient_does_not():
    params = nets.convert(offpolicy_jax.SACFamilyLearner(sac, CONFIG, SPEC).init_params(np.array([0, 1])),
                          offpolicy_jax.XP)
    assert set(params["critic"]) == {"net", "encoder"}
    assert params["actor"][0]["w"].shape[0] == OBS + CONFIG.feature_dim  # obs ++ features
    assert params["critic"]["net"][0]["w"].shape[1] == OBS + CONFIG.feature_dim + A
    rng = np.random.default_rng(0)
    n = 16  # rows of the minibatch
    mb = {k: jnp.asarray(v[0, :n]) for k, v in _batch(rng).items()}
    mb = {**mb, "terminated": jnp.zeros(n), "truncated": jnp.zeros(n)}  # bootstrapped: the target encoder is used
    stats = normalizer.stats_init(OBS, offpolicy_jax.XP)
    norms = Norms(stats, stats, jnp.ones(()))
    eps = jnp.asarray(rng.normal(size=(n, A)).astype(np.float32))
    log_alpha = jnp.asarray(np.log(0.2), jnp.float32)
    critic_loss, actor_loss = image_obs.critic_loss(sac), image_obs.actor_loss(sac)

    def norm(tree) -> float:
        return float(sum(jnp.sum(jnp.abs(x)) for x in jax.tree_util.tree_leaves(tree)))

    c_loss = lambda c, t: critic_loss(c, t, params["actor"], log_alpha, norms, mb, eps, CONFIG)[0]  # noqa: E731
    c_grads, t_grads = _grads(c_loss)(params["critic"], params["target_critic"])
    assert norm(c_grads["encoder"]) > 1e-3 and norm(c_grads["net"]) > 1e-3  # the critic trains the encoder
    assert norm(t_grads) == 0.0  # the target (and its encoder) are constants
    a_loss = lambda a, c: actor_loss(a, c, log_alpha, norms, mb, eps, CONFIG)[0]  # noqa: E731
    a_grads, q_grads = _grads(a_loss)(params["actor"], params["critic"])
    assert norm(a_grads) > 1e-4
    assert norm(q_grads["encoder"]) == 0.0  # the actor loss never reaches the encoder
    assert norm(q_grads["net"]) > 1e-4  # (only because the encoder's features are stopped)


def test_actor_encoder_is_the_actors_own():
    """``actor_encoder`` (the asymmetric actor-critic): the actor loss trains the actor's encoder and never the
    critic's, the critic loss never moves the actor, and the published policy reads the actor's encoder only (a
    change of the critic's leaves its actions as they were)."""
    config = dataclasses.replace(CONFIG, actor_encoder=True)
    learner = offpolicy_jax.SACFamilyLearner(sac, config, SPEC)
    params = nets.convert(learner.init_params(np.array([2, 3])), offpolicy_jax.XP)
    assert set(params["actor"]) == {"net", "encoder"} and set(params["critic"]) == {"net", "encoder"}
    rng = np.random.default_rng(2)
    n = 16
    mb = {k: jnp.asarray(v[0, :n]) for k, v in _batch(rng).items()}
    mb = {**mb, "terminated": jnp.zeros(n), "truncated": jnp.zeros(n)}
    stats = normalizer.stats_init(OBS, offpolicy_jax.XP)
    norms = Norms(stats, stats, jnp.ones(()))
    eps = jnp.asarray(rng.normal(size=(n, A)).astype(np.float32))
    log_alpha = jnp.asarray(np.log(0.2), jnp.float32)
    total = lambda tree: float(sum(jnp.sum(jnp.abs(x)) for x in jax.tree_util.tree_leaves(tree)))  # noqa: E731
    a_loss = lambda a, c: image_obs.actor_loss(sac)(a, c, log_alpha, norms, mb, eps, config)[0]  # noqa: E731
    a_grads, q_grads = _grads(a_loss)(params["actor"], params["critic"])
    assert total(a_grads["encoder"]) > 1e-4 and total(a_grads["net"]) > 1e-4
    assert total(q_grads["encoder"]) == 0.0
    c_loss = lambda c, a: image_obs.critic_loss(sac)(c, params["target_critic"], a, log_alpha, norms, mb, eps,  # noqa: E731
                                                     config)[0]
    c_grads, from_actor = _grads(c_loss)(params["critic"], params["actor"])
    assert total(c_grads["encoder"]) > 1e-3 and total(from_actor) == 0.0

    np_params = nets.to_numpy(params)
    weights = image_obs.add_encoder(sac.policy_weights(np_params["actor"], nets.to_numpy(stats)), np_params["actor"],
                                    np_params["critic"], config)
    assert weights["encoder"] is np_params["actor"]["encoder"] and weights["actor"] is np_params["actor"]["net"]
    img, _ = _images(rng, 8)
    obs, noise = rng.normal(size=(8, OBS)).astype(np.float32), np.zeros((8, A), np.float32)
    act = lambda w: sac.act(w, obs, noise, True, image=img)[0]  # noqa: E731
    scaled = lambda enc: {**enc, "linear": {**enc["linear"], "w": enc["linear"]["w"] * 3.0}}  # noqa: E731
    other_critic = image_obs.add_encoder(weights, np_params["actor"],
                                         {**np_params["critic"], "encoder": scaled(np_params["critic"]["encoder"])},
                                         config)
    np.testing.assert_array_equal(act(other_critic), act(weights))
    other_actor = {**weights, "encoder": scaled(weights["encoder"])}
    assert not np.allclose(act(other_actor), act(weights))


def test_one_compile_target_encoder_weights_and_numpy_act():
    learner = _learner()
    rng = np.random.default_rng(1)
    state = learner.init(jax.random.PRNGKey(1))
    first, _ = learner.update(state, _batch(rng))
    second, metrics = learner.update(first, _batch(rng))
    assert learner.trace_count == 1 and int(second.steps) == 2 * U
    assert all(np.isfinite(float(v)) for v in metrics.values()), metrics
    enc0, enc2 = state.critic["encoder"]["convs"][0]["w"], second.critic["encoder"]["convs"][0]["w"]
    tgt0, tgt2 = state.target_critic["encoder"]["convs"][0]["w"], second.target_critic["encoder"]["convs"][0]["w"]
    np.testing.assert_array_equal(np.asarray(enc0), np.asarray(tgt0))  # the target starts as a copy
    moved, followed = float(jnp.max(jnp.abs(enc2 - enc0))), float(jnp.max(jnp.abs(tgt2 - tgt0)))
    assert moved > 1e-3 and 0.0 < followed < moved  # Polyak (tau = 0.005) trails the online encoder

    weights = learner.weights(second)
    assert set(weights) == {"actor", "obs_norm", "encoder", "encoder_strides"}
    np.testing.assert_array_equal(np.asarray(weights["encoder_strides"]), CONFIG.encoder_strides)
    img, _ = _images(rng, 8)
    obs = rng.normal(size=(8, OBS)).astype(np.float32)
    noise = rng.normal(size=(8, A)).astype(np.float32)
    w_np = nets.to_numpy(weights)
    got, _ = sac.act(w_np, obs, noise, False, image=img)  # what a rollout worker runs
    on_jax, _ = sac.act(weights, jnp.asarray(obs), jnp.asarray(noise), False, image=img)
    # the policy the learner trains: actor on normalize(obs) ++ features of the online encoder
    feat = pixels.encode(second.critic["encoder"], jnp.asarray(img), CONFIG.encoder_strides)
    mean, log_std = sac.policy(second.actor, image_obs.widen_stats(second.obs_norm, CONFIG.feature_dim),
                               jnp.concatenate([jnp.asarray(obs), feat], -1))
    want = np.tanh(np.asarray(mean) + np.exp(np.asarray(log_std)) * noise)
    np.testing.assert_allclose(got, want, atol=1e-5)
    np.testing.assert_allclose(np.asarray(on_jax), want, atol=1e-5)
    assert np.std(sac.act(w_np, obs, noise, True, image=img[::-1])[0] - sac.act(w_np, obs, noise, True, image=img)[0])
    with pytest.raises(ValueError, match="needs image="):
        sac.act(w_np, obs, noise)
    with pytest.raises(ValueError, match="no encoder"):
        sac.act({"actor": w_np["actor"], "obs_norm": w_np["obs_norm"]}, obs, noise, image=img)


def test_sacflow_act_reads_images():
    """SAC Flow's worker-side chain on obs ++ features: numpy equals jax on the same weights; the image matters."""
    config = sacflow.Config(actor_hidden=(16,), critic_hidden=(16,), flow_steps=3, encoder_channels=(8,),
                            encoder_strides=(2,), feature_dim=5)
    learner = offpolicy_jax.SACFamilyLearner(sacflow, config, SPEC)
    params = nets.to_numpy(learner.init_params(np.array([3, 4])))
    stats = normalizer.RunningStats(np.full(OBS, 0.5, np.float32), np.full(OBS, 2.0, np.float32), np.float32(10.0))
    weights = image_obs.add_encoder(sac.policy_weights(params["actor"], stats), params["actor"], params["critic"],
                                  config)
    rng = np.random.default_rng(3)
    img, _ = _images(rng, 6)
    obs, noise = rng.normal(size=(6, OBS)).astype(np.float32), rng.normal(size=(6, sacflow.noise_dim(A)))
    noise = noise.astype(np.float32)
    got, _ = sacflow.act(weights, obs, noise, False, image=img)
    on_jax, _ = sacflow.act(nets.convert(weights, offpolicy_jax.XP), jnp.asarray(obs), jnp.asarray(noise), False,
                            image=img)
    np.testing.assert_allclose(np.asarray(on_jax), got, atol=1e-5)
    assert got.shape == (6, A) and not np.allclose(sacflow.act(weights, obs, noise, False, image=img[::-1])[0], got)


def test_learns_an_image_bandit():
    """The best action (+-0.5) is a function of the image only (the square's side): the greedy actor, which sees
    the critic-trained encoder's features detached, must find it. Action error E(a - best)^2 after 600 gradient
    steps (150 calls of U = 4), 10 seeds measured: 0.004 to 0.064 (this seed: 0.015; chance, a = 0: 0.25)."""
    learner = _learner()
    rng = np.random.default_rng(1)
    test_img, test_best = _images(np.random.default_rng(1001), 256)
    test_obs = np.random.default_rng(7).normal(size=(256, OBS)).astype(np.float32)

    def error(state) -> float:
        action, _ = sac.act(nets.to_numpy(learner.weights(state)), test_obs, np.zeros((256, A), np.float32), True,
                            image=test_img)
        return float(np.mean((action[:, 0] - test_best) ** 2))

    state = learner.init(jax.random.PRNGKey(1))
    start = error(state)
    for _ in range(150):
        state, metrics = learner.update(state, _batch(rng))
    final = error(state)
    assert start > 0.2 and final < 0.15, f"action error {start:.3f} -> {final:.3f}; last metrics {metrics}"
