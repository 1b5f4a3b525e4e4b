"""What the JAX and MLX off-policy learners share, written once against the shim.

``learner_jax`` and ``learner_mlx`` differ only in how they drive the gradient steps (``lax.scan`` in
one jit; a compiled step in a Python loop), how they draw noise, and in how they take gradients and apply
optimizer updates (jax and optax; mlx and ``unilab_mlx.optim``, which has optax's names and state layout),
handed to the steps here as :class:`Ops`. Everything else is here: the optimizer choice, network
initialisation on numpy, the batch fields, the once-per-call normalizer step, the initial states,
the order of one gradient step (:func:`sac_step`, :func:`td3_step`), the published weights and the metric
averaging.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from types import ModuleType
from typing import Any, NamedTuple

import numpy as np

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.algos import contract
from unilab_jax.algos.offpolicy import image_obs, sac, td3
from unilab_jax.algos.offpolicy.sac import Norms, SACState
from unilab_jax.algos.offpolicy.td3 import TD3State
from unilab_jax.core import normalizer, polyak
from unilab_jax.fields import IMAGE_FIELDS
from unilab_jax.fields import REPLAY_FIELDS as BATCH_FIELDS

NP = shim.get("numpy")
# compute_dtype "auto", per jax backend (jax.default_backend()); other backends: float32.
AUTO_COMPUTE_DTYPE = {"cpu": "float32", "gpu": "bfloat16", "cuda": "bfloat16", "rocm": "bfloat16"}


def compute_dtype(config: Any, backend: str) -> str:
    """The matrix-multiply dtype a learner on ``backend`` ("cpu", "gpu", ..., "mlx") uses for ``config``."""
    name = config.compute_dtype
    if name == "auto":
        return AUTO_COMPUTE_DTYPE.get(backend, "float32")
    if backend == "mlx" and name != "float32":
        raise ValueError(f"compute_dtype={name!r}: the MLX learners compute in float32 (use 'float32' or 'auto')")
    return name


def resolve_ln_kernels(config: Any, compute_dtype: str, devices: list[Any]) -> tuple[str, str]:
    """The (forward, backward) kernels of the bf16 LayerNorm + ReLU layers for ``config.ln_forward`` /
    ``ln_backward`` on ``devices``: "auto" is "pallas" for a bf16 learner on ONE NVIDIA GPU of compute capability
    >= 8 (Ampere and later: bf16 in Triton; the fused kernels take the H100 learner from 514 to 605 gradient steps/s,
    docs/perf/learner_scaling.md section 16), else "xla" (CPU, ROCm, several devices, float32)."""
    one_cuda_gpu = len(devices) == 1 and _cuda_major(devices[0]) >= 8
    auto = "pallas" if one_cuda_gpu and compute_dtype == "bfloat16" else "xla"
    return tuple(auto if name == "auto" else name for name in (config.ln_forward, config.ln_backward))


def _cuda_major(device: Any) -> int:
    """The CUDA compute capability's major number of a jax ``device``; 0 for any other device."""
    names = f"{getattr(device.client, 'platform_version', '')} {getattr(device, 'device_kind', '')}".lower()
    if device.platform != "gpu" or ("cuda" not in names and "nvidia" not in names):
        return 0
    try:
        return int(str(getattr(device, "compute_capability", "0")).split(".")[0])
    except ValueError:
        return 0


def make_optimizer(opt: ModuleType, learning_rate: float, weight_decay: float = 0.0,
                   max_grad_norm: float = 0.0, flat: bool = False) -> Any:
    """Adam (AdamW when ``weight_decay`` > 0), after global-norm clipping when ``max_grad_norm`` > 0;
    ``opt`` is optax or ``unilab_mlx.optim``. ``flat`` (optax only): the chain runs on one vector of all the
    parameters (``optax.flatten``): the same arithmetic element by element, in a few fused kernels instead of a few
    per parameter array (on the H100, 93 parameter-shaped kernels per gradient step: docs/perf/learner_scaling.md
    section 1); its moments are then flat vectors."""
    parts = []
    if max_grad_norm > 0:
        parts.append(opt.clip_by_global_norm(max_grad_norm))
    parts.append(opt.adamw(learning_rate, weight_decay=weight_decay) if weight_decay > 0
                 else opt.adam(learning_rate))
    if flat and not hasattr(opt, "flatten"):
        raise ValueError("flat_optimizer=True: the JAX learners only (the MLX optimizers keep one state per array)")
    return opt.flatten(opt.chain(*parts)) if flat else opt.chain(*parts)


def init_on_numpy(init_params: Any, key_words: np.ndarray, xp: shim.Backend, *args: Any,
                  targets: tuple[str, ...] = ()) -> dict:
    """Runs ``init_params(np_key, *args, xp=numpy)`` and moves the result to ``xp``, adding an
    independent copy ``target_<name>`` of each network named in ``targets``.

    ``key_words``: the platform key's uint32 words; the numpy key is the first two, so both platforms
    initialise the same parameters bit for bit. Network initialisation is hundreds of small random
    ops: eagerly in jax each compiles on first use (seconds at start-up), in numpy they are instant.
    """
    np_key = np.asarray(key_words, dtype=np.uint32).reshape(-1)[:2]
    params = init_params(np_key, *args, xp=NP)
    params.update({f"target_{name}": params[name] for name in targets})
    return {k: nets.convert(v, xp) for k, v in params.items()}  # separate buffers per entry


def prepare_batch(batch: dict, fields: tuple[str, ...] = BATCH_FIELDS) -> dict:
    """The ``fields`` the update reads, rewards/flags as float32 (bool flags accepted; images stay uint8)."""
    missing = [k for k in fields if k not in batch]
    if missing:
        raise ValueError(f"the replay batch lacks {missing} (it has {sorted(batch)})")
    out = {k: batch[k] for k in fields}
    xp = shim.namespace(out["reward"])
    for k in ("reward", "terminated", "truncated"):
        out[k] = xp.astype(out[k], xp.float32)
    return out


# Per-step metrics of the actor and temperature update (zero on the steps ``actor_every`` skips).
ACTOR_METRICS = ("actor_loss", "entropy", "policy_std", "alpha_loss", "actor_grad_norm")


def update_obs_stats(obs_norm: normalizer.RunningStats, critic_norm: normalizer.RunningStats, batch: dict,
                     enabled: bool) -> tuple[normalizer.RunningStats, normalizer.RunningStats]:
    """Normalizer statistics moved once per call, by the first of the U minibatches."""
    if not enabled:
        return obs_norm, critic_norm
    return (normalizer.stats_update(obs_norm, batch["obs"][0]),
            normalizer.stats_update(critic_norm, batch["critic_obs"][0]))


def mean_metrics(stacked: dict) -> dict:
    """Per-step metrics stacked to ``[U]`` -> their means."""
    return {k: shim.namespace(v).mean(v) for k, v in stacked.items()}


def td3_metrics(stacked: dict) -> dict:
    """TD3's per-call metrics from ``[U]`` stacks: means, with the actor loss averaged over the steps
    that updated the actor (0 when none did in this call) and their count."""
    stacked = dict(stacked)
    xp = shim.namespace(stacked["actor_steps"])
    actor_steps = xp.sum(stacked.pop("actor_steps"))
    actor_loss_sum = xp.sum(stacked.pop("actor_loss_sum"))
    metrics = mean_metrics(stacked)
    metrics["actor_loss"] = actor_loss_sum / xp.maximum(actor_steps, 1.0)
    metrics["actor_steps"] = actor_steps
    return metrics


class SACFamilyBase:
    """The platform-independent half of the SAC-family learners (``algo`` is the algorithm module, a
    ``contract.SACFamilyDeclaration``: ``init_params``, ``critic_loss``, ``actor_loss``, ``temperature_loss``;
    its optional hooks, e.g. ``project_params`` and ``reward_scale``, come from ``contract.hooks``).

    A task with images (``spec.image_shape``; ``image_obs``): the learners use ``self.critic_loss`` /
    ``self.actor_loss`` (the algorithm's, wrapped to encode the images), read ``self.batch_fields`` and put each
    gradient step's DrQ offsets (``image_obs.shift_shape``, uniform in ``[0, 2 image_pad]``, from the last key
    of the step's split) in the minibatch for ``augment``."""

    def __init__(self, algo: ModuleType, config: Any, spec: Any, opt: ModuleType, xp: shim.Backend):
        self.algo, self.config, self.spec, self.xp = algo, config, spec, xp
        image_obs.check_algo(algo, spec, config)
        self.image_shape = image_obs.image_shape(spec)
        self.critic_loss, self.actor_loss = algo.critic_loss, algo.actor_loss
        self.batch_fields = BATCH_FIELDS
        if self.image_shape:
            self.critic_loss, self.actor_loss = image_obs.critic_loss(algo), image_obs.actor_loss(algo)
            self.batch_fields = BATCH_FIELDS + IMAGE_FIELDS
        self.actor_tx = make_optimizer(opt, config.actor_learning_rate, config.weight_decay, config.max_grad_norm,
                                       config.flat_optimizer)
        self.critic_tx = make_optimizer(opt, config.critic_learning_rate, config.weight_decay, config.max_grad_norm,
                                        config.flat_optimizer)
        self.alpha_tx = opt.adam(config.alpha_learning_rate)
        self.target_entropy = float(config.target_entropy_per_dim * spec.action_dim)
        hooks = contract.hooks(algo)  # the optional hooks, defaults filled in
        # Standard normals per sample of the policy's reparameterised draw (SAC: |A|; SAC Flow: its chain).
        self.noise_dim = hooks.learner_noise_dim(config, spec.action_dim)
        self.project = hooks.project
        self._reward_scale = hooks.reward_scale
        # An algorithm with ``critic_noise_shape(config)`` (RLPD) gets ``(eps_next, u)`` in its critic loss,
        # ``u`` uniform of that shape, drawn per gradient step from a third key of the step's split.
        shape = hooks.critic_noise_shape
        self.critic_noise_shape = None if shape is None else tuple(shape(config))
        # ``actor_every`` (RLPD): the actor and the temperature move on every actor_every-th gradient step only.
        self.actor_every = int(hooks.actor_every(config))
        # Keys per gradient step: eps_next, eps[, the critic noise u][, the DrQ offsets].
        self.step_keys = 2 + (self.critic_noise_shape is not None) + bool(self.image_shape)
        self.trace_count = 0  # traces of the compiled update / step (tests assert no retracing)

    def init_params(self, key_words: np.ndarray) -> dict:
        s = self.spec
        init = self.algo.init_params
        if self.image_shape:
            init = functools.partial(image_obs.init_params, self.algo, self.image_shape)
        return init_on_numpy(init, key_words, self.xp, s.obs_dim, s.critic_obs_dim, s.action_dim,
                             self.config, targets=("critic",))

    def draw_shifts(self, key: Any, batch_size: int) -> Any:
        """A gradient step's DrQ offsets [2, B, 2], uniform in ``[0, 2 image_pad]``."""
        return self.xp.random.randint(key, image_obs.shift_shape(batch_size), 0, 2 * self.config.image_pad + 1)

    def augment(self, mb: dict) -> dict:
        """The minibatch with its images shifted (without images: unchanged)."""
        return image_obs.augment(mb, self.config.image_pad) if self.image_shape else mb

    def call_metrics(self, stacked: dict) -> dict:
        """A call's metrics from their ``[U]`` stacks: means; with ``actor_every`` > 1 the actor's metrics
        (``ACTOR_METRICS``) are averaged over the steps that moved the actor, whose count is ``actor_steps``."""
        if self.actor_every == 1:
            return mean_metrics(stacked)
        stacked = dict(stacked)
        xp = shim.namespace(stacked["actor_steps"])
        count = xp.sum(stacked.pop("actor_steps"))
        delayed = {k: xp.sum(stacked.pop(k)) / xp.maximum(count, 1.0) for k in ACTOR_METRICS if k in stacked}
        return {**mean_metrics(stacked), **delayed, "actor_steps": count}

    def initial_state(self, params: dict, k_state: Any) -> SACState:
        s, xp = self.spec, self.xp
        log_alpha = xp.full((), math.log(self.config.init_alpha), dtype=xp.float32)
        return SACState(
            actor=params["actor"], critic=params["critic"], target_critic=params["target_critic"],
            actor_opt=self.actor_tx.init(params["actor"]), critic_opt=self.critic_tx.init(params["critic"]),
            log_alpha=log_alpha, alpha_opt=self.alpha_tx.init(log_alpha),
            obs_norm=normalizer.stats_init(s.obs_dim, xp), critic_norm=normalizer.stats_init(s.critic_obs_dim, xp),
            reward_norm=normalizer.stats_init(1, xp), key=k_state, steps=xp.zeros((), dtype=xp.int32))

    def weights(self, state: SACState) -> dict:
        weights = sac.policy_weights(state.actor, state.obs_norm)
        return image_obs.add_encoder(weights, state.actor, state.critic, self.config) if self.image_shape else weights

    def reward_scale(self, state: SACState) -> Any:
        if self._reward_scale is None:
            return self.xp.ones((), dtype=self.xp.float32)
        return self._reward_scale(state.reward_norm, self.config)

    def normalize(self, state: SACState, batch: dict) -> tuple[SACState, Norms]:
        """The call's normalizer step (observations, and rewards where the algorithm scales them) and
        the norms every gradient step of the call uses."""
        obs_norm, critic_norm = update_obs_stats(state.obs_norm, state.critic_norm, batch, self.config.normalize_obs)
        reward_norm = state.reward_norm
        if self._reward_scale is not None:
            reward_norm = normalizer.stats_update(reward_norm, batch["reward"][0][:, None])
        state = state._replace(obs_norm=obs_norm, critic_norm=critic_norm, reward_norm=reward_norm)
        return state, Norms(obs_norm, critic_norm, self.xp.astype(self.reward_scale(state), self.xp.float32))


class Ops(NamedTuple):
    """How a platform takes gradients and applies updates; the gradient steps' order around them is written once
    (:func:`sac_step`, :func:`td3_step`)."""

    value_and_grad: Callable  # (fn, has_aux=False) -> fn's (value, gradient w.r.t. its first argument)
    apply_updates: Callable  # (params, optimizer updates) -> params
    global_norm: Callable  # pytree -> its global L2 norm
    cond: Callable  # (pred, true_fn, false_fn, *operands) -> the chosen function's result (lax.cond; a Python if)
    # (actor_step, *operands) -> the metrics of a step that leaves the actor: zeros with actor_step's structure
    skip_metrics: Callable


class SACNets(NamedTuple):
    """What one SAC-family gradient step reads and moves (a ``SACState``'s fields of those names)."""

    actor: Any
    critic: Any
    target_critic: Any
    actor_opt: Any
    critic_opt: Any
    log_alpha: Any
    alpha_opt: Any
    steps: Any


def sac_nets(state: SACState) -> SACNets:
    """The fields of ``state`` a gradient step moves."""
    return SACNets(state.actor, state.critic, state.target_critic, state.actor_opt, state.critic_opt, state.log_alpha,
                   state.alpha_opt, state.steps)


def sac_step(learner: SACFamilyBase, ops: Ops, nets: SACNets, norms: Norms, mb: dict, eps_next: Any, eps: Any,
             do_actor: Any = True) -> tuple[SACNets, dict]:
    """One SAC-family gradient step, pure in its arguments: 1. the critics; 2. the actor against the updated
    critics, 3. the temperature (both on the steps ``do_actor`` marks when ``learner.actor_every`` > 1); 4. the
    target critics (Polyak); the step's metrics. ``learner``: its losses, optimizers, ``project`` and settings;
    ``eps_next``, ``eps``: the step's draws (RLPD: ``eps_next = (eps_next, u)``); ``mb`` already augmented."""
    cfg, xp, project = learner.config, learner.xp, learner.project
    # 1. critics
    (_, c_metrics), c_grads = ops.value_and_grad(learner.critic_loss, has_aux=True)(
        nets.critic, nets.target_critic, nets.actor, nets.log_alpha, norms, mb, eps_next, cfg)
    updates, critic_opt = learner.critic_tx.update(c_grads, nets.critic_opt, nets.critic)
    critic = project(ops.apply_updates(nets.critic, updates))

    def actor_step(nets: SACNets, critic: Any, mb: dict, eps: Any) -> tuple[tuple, dict]:
        # 2. actor, against the updated critics
        (_, (a_metrics, log_prob)), a_grads = ops.value_and_grad(learner.actor_loss, has_aux=True)(
            nets.actor, critic, nets.log_alpha, norms, mb, eps, cfg)
        updates, actor_opt = learner.actor_tx.update(a_grads, nets.actor_opt, nets.actor)
        actor = project(ops.apply_updates(nets.actor, updates))
        # 3. temperature
        log_alpha, alpha_opt, alpha_loss = nets.log_alpha, nets.alpha_opt, xp.zeros((), dtype=xp.float32)
        if cfg.autotune_alpha:
            alpha_loss, g = ops.value_and_grad(learner.algo.temperature_loss)(nets.log_alpha, log_prob,
                                                                              learner.target_entropy)
            updates, alpha_opt = learner.alpha_tx.update(g, nets.alpha_opt, nets.log_alpha)
            log_alpha = ops.apply_updates(nets.log_alpha, updates)
        return (actor, actor_opt, log_alpha, alpha_opt), {**a_metrics, "alpha_loss": alpha_loss,
                                                          "actor_grad_norm": ops.global_norm(a_grads)}

    def skip_actor(nets: SACNets, critic: Any, mb: dict, eps: Any) -> tuple[tuple, dict]:
        return ((nets.actor, nets.actor_opt, nets.log_alpha, nets.alpha_opt),
                ops.skip_metrics(actor_step, nets, critic, mb, eps))

    if learner.actor_every == 1:
        (actor, actor_opt, log_alpha, alpha_opt), a_metrics = actor_step(nets, critic, mb, eps)
    else:
        (actor, actor_opt, log_alpha, alpha_opt), a_metrics = ops.cond(do_actor, actor_step, skip_actor, nets,
                                                                        critic, mb, eps)
        a_metrics["actor_steps"] = xp.asarray(do_actor, dtype=xp.float32)
    # 4. targets
    target_critic = project(polyak.polyak(nets.target_critic, critic, cfg.tau))
    metrics = {**c_metrics, **a_metrics, "alpha": xp.exp(log_alpha), "critic_grad_norm": ops.global_norm(c_grads)}
    return SACNets(actor, critic, target_critic, actor_opt, critic_opt, log_alpha, alpha_opt, nets.steps + 1), metrics


class TD3Nets(NamedTuple):
    """What one TD3 gradient step reads and moves (a ``TD3State``'s fields of those names)."""

    actor: Any
    critic: Any
    target_actor: Any
    target_critic: Any
    actor_opt: Any
    critic_opt: Any
    steps: Any


def td3_nets(state: TD3State) -> TD3Nets:
    """The fields of ``state`` a gradient step moves."""
    return TD3Nets(state.actor, state.critic, state.target_actor, state.target_critic, state.actor_opt,
                   state.critic_opt, state.steps)


def td3_step(learner: TD3Base, ops: Ops, nets: TD3Nets, norms: Norms, mb: dict, eps_next: Any,
             do_actor: Any) -> tuple[TD3Nets, dict]:
    """One TD3 gradient step, pure in its arguments: the critics; then, on the steps ``do_actor`` marks (every
    ``policy_delay``-th, Fujimoto's schedule), the actor against the updated critics and both target networks
    (Polyak); the step's metrics (``td3_metrics`` averages them)."""
    cfg, xp = learner.config, learner.xp
    (_, c_metrics), c_grads = ops.value_and_grad(td3.critic_loss, has_aux=True)(
        nets.critic, nets.target_actor, nets.target_critic, norms, mb, eps_next, cfg)
    updates, critic_opt = learner.critic_tx.update(c_grads, nets.critic_opt, nets.critic)
    nets = nets._replace(critic=ops.apply_updates(nets.critic, updates), critic_opt=critic_opt)

    def actor_step(nets: TD3Nets, mb: dict) -> tuple[TD3Nets, Any]:
        (loss, _), grads = ops.value_and_grad(td3.actor_loss, has_aux=True)(nets.actor, nets.critic, norms, mb)
        updates, actor_opt = learner.actor_tx.update(grads, nets.actor_opt, nets.actor)
        actor = ops.apply_updates(nets.actor, updates)
        return nets._replace(actor=actor, actor_opt=actor_opt,
                             target_actor=polyak.polyak(nets.target_actor, actor, cfg.tau),
                             target_critic=polyak.polyak(nets.target_critic, nets.critic, cfg.tau)), loss

    def skip_actor(nets: TD3Nets, mb: dict) -> tuple[TD3Nets, Any]:
        return nets, xp.zeros((), dtype=xp.float32)

    nets, a_loss = ops.cond(do_actor, actor_step, skip_actor, nets, mb)
    metrics = {**c_metrics, "actor_loss_sum": a_loss, "actor_steps": xp.asarray(do_actor, dtype=xp.float32),
               "critic_grad_norm": ops.global_norm(c_grads)}
    return nets._replace(steps=nets.steps + 1), metrics


class TD3Base:
    """The platform-independent half of the TD3 learners: delayed actor and target updates every
    ``policy_delay`` gradient steps."""

    def __init__(self, config: Any, spec: Any, opt: ModuleType, xp: shim.Backend):
        image_obs.check_algo(td3, spec, config)
        self.config, self.spec, self.xp = config, spec, xp
        self.actor_tx = make_optimizer(opt, config.actor_learning_rate, config.weight_decay, config.max_grad_norm,
                                       config.flat_optimizer)
        self.critic_tx = make_optimizer(opt, config.critic_learning_rate, config.weight_decay, config.max_grad_norm,
                                        config.flat_optimizer)
        self.trace_count = 0

    def init_params(self, key_words: np.ndarray) -> dict:
        s = self.spec
        return init_on_numpy(td3.init_params, key_words, self.xp, s.obs_dim, s.critic_obs_dim, s.action_dim,
                             self.config, targets=("actor", "critic"))

    def initial_state(self, params: dict, k_state: Any) -> TD3State:
        s, xp = self.spec, self.xp
        return TD3State(
            actor=params["actor"], critic=params["critic"], target_actor=params["target_actor"],
            target_critic=params["target_critic"], actor_opt=self.actor_tx.init(params["actor"]),
            critic_opt=self.critic_tx.init(params["critic"]),
            obs_norm=normalizer.stats_init(s.obs_dim, xp), critic_norm=normalizer.stats_init(s.critic_obs_dim, xp),
            explore_std=xp.asarray(self.config.explore_std, dtype=xp.float32), key=k_state,
            steps=xp.zeros((), dtype=xp.int32))

    @staticmethod
    def weights(state: TD3State) -> dict:
        return {"actor": state.actor, "obs_norm": state.obs_norm, "explore_std": state.explore_std}

    def normalize(self, state: TD3State, batch: dict) -> tuple[TD3State, Norms]:
        obs_norm, critic_norm = update_obs_stats(state.obs_norm, state.critic_norm, batch, self.config.normalize_obs)
        return (state._replace(obs_norm=obs_norm, critic_norm=critic_norm),
                Norms(obs_norm, critic_norm, self.xp.ones((), dtype=self.xp.float32)))
