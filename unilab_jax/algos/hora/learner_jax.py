"""JAX learners of HORA: the PPO teacher (``ppo_jax.Learner`` with another actor) and the student's
adaptation-module regression (one jitted update, scans over epochs and minibatches inside)."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from unilab_jax import nets, nets_temporal
from unilab_jax import xp as shim
from unilab_jax.algos.hora import common as hora
from unilab_jax.algos.hora.student import HoraStudentConfig
from unilab_jax.algos.hora.teacher import HoraTeacherConfig
from unilab_jax.algos.ppo import learner_jax as ppo_jax
from unilab_jax.algos.ppo import ppo
from unilab_jax.core import adaptation as hora_core
from unilab_jax.core import normalizer
from unilab_jax.core.normalizer import RunningStats

XP = shim.get("jax")


def make_teacher_learner(algo: Any, config: HoraTeacherConfig, spec: Any) -> TeacherLearner:
    """The registry's factory for ``hora_teacher`` (after its spec check)."""
    algo.check_spec(spec)
    return TeacherLearner(config, spec)


def make_student_learner(algo: Any, config: HoraStudentConfig, spec: Any) -> StudentLearner:
    """The registry's factory for ``hora_student`` (after its spec check)."""
    algo.check_spec(spec)
    return StudentLearner(config, spec)


class TeacherLearner(ppo_jax.Learner):
    """PPO with the policy on ``[current frame, tanh(mlp(extrinsics))]``; everything else is PPO's."""

    actor = staticmethod(hora.teacher_actor)

    def __init__(self, config: HoraTeacherConfig, spec: Any):
        super().__init__(config, spec, use_vtrace=False)

    def init_params(self, key: jax.Array) -> dict:
        cfg, s = self.config, self.spec
        k_ppo, k_enc = jax.random.split(key)
        params = ppo.init_params(k_ppo, s.frame_dim + cfg.z_dim, s.critic_obs_dim, s.action_dim, cfg, XP)
        params["encoder"] = nets.init(k_enc, [s.privileged_dim, *cfg.encoder_hidden, cfg.z_dim], XP)
        return params

    @staticmethod
    def weights(state: ppo.TrainState) -> dict:
        p = state.params
        return {"actor": p["actor"], "encoder": p["encoder"], "log_std": p["log_std"], "obs_norm": state.obs_norm}


class StudentState(NamedTuple):
    """The student's training state; the teacher's pieces ride along frozen (self-contained checkpoints)."""

    params: dict  # {"adapt": adaptation module}: the only trained parameters
    opt_state: Any
    teacher: dict  # {"actor", "log_std", "encoder"} of the stage-1 teacher (frozen)
    history_norm: RunningStats  # [H, d]: the teacher's frame statistics, per history position (frozen)
    ext_norm: RunningStats  # [p]: the teacher's extrinsics statistics (frozen)
    key: Any
    updates: Any  # int32
    z_mse0: Any  # the z error measured before the first update (reference of z_mse_ratio)


def load_teacher(checkpoint_dir: str, spec: Any) -> tuple[dict, RunningStats, dict]:
    """(teacher params, teacher obs normalizer, checkpoint meta) from a ``hora_teacher`` run's checkpoints.

    The template is built from the teacher's own recorded config and this task's frame/extrinsics sizes,
    so a teacher trained on another frame layout is refused with the mismatched leaf named.
    """
    from unilab_jax.checkpoint import Checkpointer, fill
    from unilab_jax.config import apply_overrides

    ckpt = Checkpointer(checkpoint_dir)
    try:
        if ckpt.latest_step() is None:
            raise FileNotFoundError(f"teacher_checkpoint: no checkpoint under {checkpoint_dir!r}")
        _, values, meta = ckpt.read()
    finally:
        ckpt.close()
    if meta.get("algo") != "hora_teacher":
        raise ValueError(f"teacher_checkpoint {checkpoint_dir!r} holds a {meta.get('algo')!r} run, not hora_teacher")
    cfg = apply_overrides(HoraTeacherConfig(), meta["config"])
    params = TeacherLearner(cfg, spec).init_params(XP.random.key(0))
    obs_dim = int(np.shape(values["obs_norm/mean"])[0])
    template = {"params": params, "obs_norm": normalizer.stats_init(obs_dim, XP)}
    values = {p: v for p, v in values.items() if p.split("/", 1)[0] in template}
    restored = fill(template, values, lambda a, like: jnp.asarray(a))
    return restored["params"], restored["obs_norm"], meta


class StudentLearner:
    """``init(key) -> StudentState`` (restores the teacher); ``update(state, batch)``; ``weights(state)``."""

    def __init__(self, config: HoraStudentConfig, spec: Any):
        self.config, self.spec = config, spec
        self.tx = optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.adam(config.learning_rate))
        self.update = jax.jit(self.traced_update, donate_argnums=ppo_jax.DONATE_STATE)

    def traced_update(self, state: StudentState, batch: dict) -> tuple[StudentState, dict]:
        """The pure update as this learner compiles it (``training.sharding`` compiles the same over devices)."""
        return self._update(state, batch)

    def init(self, key: jax.Array) -> StudentState:
        cfg, s = self.config, self.spec
        teacher, obs_norm, _ = load_teacher(cfg.teacher_checkpoint, s)
        d, p, z = hora.teacher_dims(teacher)
        k_adapt, k_state = jax.random.split(key)
        adapt = nets_temporal.adaptation_init(k_adapt, d, z, s.history_len, XP, hidden=cfg.adapt_hidden,
                                              channels=cfg.conv_channels, kernels=cfg.conv_kernels)
        params = {"adapt": adapt}
        _, ext_norm = hora.frame_and_extrinsics_stats(obs_norm, d, p)
        state = StudentState(params=params, opt_state=self.tx.init(params),
                             teacher={k: teacher[k] for k in ("actor", "log_std", "encoder")},
                             history_norm=hora.history_stats(obs_norm, d, p, s.history_len), ext_norm=ext_norm,
                             key=k_state, updates=jnp.zeros((), jnp.int32), z_mse0=jnp.zeros((), jnp.float32))
        return jax.tree_util.tree_map(jnp.array, state)  # own buffers: the update may donate every leaf

    def weights(self, state: StudentState) -> dict:
        return {"actor": state.teacher["actor"], "log_std": state.teacher["log_std"], "adapt": state.params["adapt"],
                "history_norm": state.history_norm,
                "noise_scale": jnp.asarray(self.config.action_noise, jnp.float32)}

    def _update(self, state: StudentState, batch: dict) -> tuple[StudentState, dict]:
        cfg = self.config
        obs = batch["obs"]
        n = obs.shape[0] * obs.shape[1]
        obs = obs.reshape(n, obs.shape[-1])
        p = state.ext_norm.mean.shape[0]
        teacher = state.teacher
        z_target = hora.latent(teacher["encoder"], normalizer.normalize(state.ext_norm, obs[:, obs.shape[1] - p:]))
        h, d = state.history_norm.mean.shape
        frames = normalizer.normalize(state.history_norm, obs[:, : h * d].reshape(n, h, d))

        def predict(params: dict, x: jax.Array) -> jax.Array:
            return jnp.tanh(nets_temporal.adaptation_apply(params["adapt"], x))

        # Measured on the new batch before fitting it: an error on data the module has not trained on.
        z_before = predict(state.params, frames)
        _, before = hora_core.adaptation_loss(z_before, z_target)
        a_teacher = hora.policy_mean(teacher["actor"], frames[:, -1], z_target)
        a_student = hora.policy_mean(teacher["actor"], frames[:, -1], z_before)
        z_mse0 = jnp.where(state.updates == 0, before["z_mse"], state.z_mse0)

        def loss_fn(params: dict, mb: dict) -> tuple[jax.Array, dict]:
            return hora_core.adaptation_loss(predict(params, mb["frames"]), mb["z"])

        grad_fn = jax.value_and_grad(loss_fn, has_aux=True)
        mb_size = n // cfg.num_minibatches

        def minibatch_step(carry: tuple, mb: dict) -> tuple[tuple, dict]:
            params, opt_state = carry
            (loss, _), grads = grad_fn(params, mb)
            updates, opt_state = self.tx.update(grads, opt_state, params)
            grad_norm = jnp.sqrt(sum(jnp.sum(jnp.square(g)) for g in jax.tree_util.tree_leaves(grads)))
            return (optax.apply_updates(params, updates), opt_state), {"z_mse_train": loss, "grad_norm": grad_norm}

        def epoch(carry: tuple, key: jax.Array) -> tuple[tuple, dict]:
            perm = jax.random.permutation(key, n)[: mb_size * cfg.num_minibatches]
            mbs = {"frames": frames[perm].reshape(cfg.num_minibatches, mb_size, h, d),
                   "z": z_target[perm].reshape(cfg.num_minibatches, mb_size, -1)}
            return jax.lax.scan(minibatch_step, carry, mbs)

        keys = jax.random.split(state.key, cfg.num_epochs + 1)
        (params, opt_state), metrics = jax.lax.scan(epoch, (state.params, state.opt_state), keys[1:])
        metrics = {**jax.tree_util.tree_map(jnp.mean, metrics), "z_mse": before["z_mse"],
                   "z_mse_ratio": before["z_mse"] / jnp.maximum(z_mse0, 1e-12), "z_target_var": before["z_target_var"],
                   "action_mse": jnp.mean(jnp.square(a_student - a_teacher))}
        new_state = state._replace(params=params, opt_state=opt_state, key=keys[0], updates=state.updates + 1,
                                   z_mse0=z_mse0)
        return new_state, metrics
