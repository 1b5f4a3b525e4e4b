"""HORA distillation and HIM-PPO learning on cart-pole through the real runtime, plus their policies' contracts."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

import tasks
from unilab_jax import algos, nets
from unilab_jax import xp as shim
from unilab_jax.algos.hora import student as hora_student
from unilab_jax.algos.hora import teacher as hora_teacher
from unilab_jax.algos.ppo import him_ppo
from unilab_jax.config import apply_overrides
from unilab_jax.training.evaluation import evaluate_policy
from unilab_jax.training.trainer import RunConfig, Trainer

jax = pytest.importorskip("jax")

PPO_CARTPOLE = {"actor_hidden": (64, 64), "critic_hidden": (64, 64), "horizon": 32, "learning_rate": 1e-3,
                "num_epochs": 5, "num_minibatches": 4, "ent_coef": 0.0, "gamma": 0.98, "desired_kl": 0.01}
# Motor strength and pole mass vary per env; frames carry the previous action (cart-pole's observation
# lacks it), so the history shows how the cart responds to a push.
DR_TASK = {"dr_motor_strength": (0.3, 1.5), "dr_pole_mass_scale": (0.5, 2.0), "history_actions": True}
HISTORY = 30


def _train(tmp_path, algo, name, overrides, recipe, steps, envs_per_worker=16, seed=0):
    module = algos.get(algo)
    run = RunConfig(algo=algo, task="cartpole_balance_hist", num_workers=2, envs_per_worker=envs_per_worker,
                    total_steps=steps, seed=seed, logdir=str(tmp_path / name), eval_envs=8)
    summary = Trainer(run, module, apply_overrides(module.Config(), recipe), overrides).train()
    with open(os.path.join(summary["logdir"], "metrics.jsonl")) as f:
        rows = [json.loads(line) for line in f]
    return summary, rows


def test_hora_student_recovers_the_latent_and_the_teachers_return(tmp_path):
    # Stage 1: the teacher reads the extrinsics through z = tanh(mlp(e)). Its final return over seeds 0-7
    # (dev VM): 183-199 at this budget (167-196 at half of it); threshold 150. The whole test passed on
    # seeds 0-5 (students 169-199).
    teacher, _ = _train(tmp_path, "hora_teacher", "teacher", {**DR_TASK, "history_len": 1},
                        {**PPO_CARTPOLE, "encoder_hidden": (32,), "z_dim": 2}, 49_152)
    assert teacher["eval/return"] >= 150.0, teacher
    # Stage 2: 256 envs (each its own dynamics) drive with the frozen teacher head on z_hat from 30 frames.
    ckpts = os.path.join(teacher["logdir"], "checkpoints")
    student_task = {**DR_TASK, "history_len": HISTORY}
    student, rows = _train(tmp_path, "hora_student", "student", student_task,
                           {"teacher_checkpoint": ckpts, "horizon": 8, "num_epochs": 4, "num_minibatches": 4,
                            "learning_rate": 2e-3, "action_noise": 1.0}, 30_720, envs_per_worker=128)
    z = np.array([r["loss/z_mse"] for r in rows if "loss/z_mse" in r])
    var = np.array([r["loss/z_target_var"] for r in rows if "loss/z_mse" in r])
    assert len(z) >= 10
    # Measured on each new batch before fitting it. Stated bounds: the last five average below 0.6 of the
    # first, and below 0.8 of the latent's variance (better than predicting the batch mean, so the history
    # really tells the extrinsics apart). Typical on the dev VM: 0.4-0.5 and 0.45-0.55.
    assert z[-5:].mean() < 0.6 * z[0], z
    assert z[-5:].mean() < 0.8 * var[-5:].mean(), (z, var)
    # Same envs and seeds for both: the student (no privileged input) keeps >= 85% of the teacher's return.
    spec = tasks.make("cartpole_balance_hist", 1, overrides=student_task).spec
    from unilab_jax.algos.hora.learner_jax import StudentLearner, load_teacher
    from unilab_jax.checkpoint import Checkpointer

    learner = StudentLearner(apply_overrides(hora_student.Config(), {"teacher_checkpoint": ckpts}), spec)
    ckpt = Checkpointer(os.path.join(student["logdir"], "checkpoints"))
    state, _ = ckpt.restore(learner.init(shim.get("jax").random.key(0)), lambda a, like: jax.numpy.asarray(a))
    ckpt.close()
    tp, obs_norm, _ = load_teacher(ckpts, spec)
    t_w = nets.to_numpy({"actor": tp["actor"], "encoder": tp["encoder"], "log_std": tp["log_std"],
                         "obs_norm": obs_norm})
    s_w = nets.to_numpy(learner.weights(state))
    t_eval = evaluate_policy(hora_teacher, t_w, "cartpole_balance_hist", student_task, 16, seed=1)
    s_eval = evaluate_policy(hora_student, s_w, "cartpole_balance_hist", student_task, 16, seed=1)
    assert s_eval["eval/return"] >= 0.85 * t_eval["eval/return"], (s_eval, t_eval)
    # The student never reads the extrinsics; the teacher does.
    env = tasks.make("cartpole_balance_hist", 8, seed=5, overrides=student_task)
    obs, _ = env.reset()
    for _ in range(40):
        obs = env.step(np.asarray(hora_student.act(s_w, obs, None, True)[0], np.float32)).obs
    scrambled = obs.copy()
    scrambled[:, -2:] = np.random.default_rng(0).uniform(-5, 5, size=(8, 2))
    np.testing.assert_array_equal(hora_student.act(s_w, obs, None, True)[0],
                                  hora_student.act(s_w, scrambled, None, True)[0])
    assert not np.allclose(hora_teacher.act(t_w, obs, None, True)[0], hora_teacher.act(t_w, scrambled, None, True)[0])


def test_him_ppo_learns_cartpole_from_positions_only(tmp_path):
    # The frames drop both velocities (observation columns 3, 4); the estimator regresses them from the
    # successor's critic observation (the same columns there) and the policy gets the estimates.
    overrides = {"history_len": 4, "history_extrinsics": False, "history_exclude": (3, 4), "history_actions": True}
    # Final return over seeds 0-7 (dev VM): 172-197 at this budget; at half of it 152-198 (a fresh machine
    # got 137 there). Threshold 130: 42 below the lowest seed, ~4x a random policy (~35).
    summary, rows = _train(tmp_path, "him_ppo", "him", overrides, {**PPO_CARTPOLE, "velocity_cols": (3, 4)}, 49_152)
    assert summary["eval/return"] >= 130.0, summary
    train = [r for r in rows if "loss/velocity_loss" in r]
    vel = np.array([r["loss/velocity_loss"] for r in train])
    swap = np.array([r["loss/swap_loss"] for r in train])
    assert vel[-3:].mean() < 0.3 * vel[0], vel
    assert swap[-3:].mean() < swap[0], swap
    assert all(0.0 < r["loss/prototype_usage"] <= 1.0 for r in train)


def _small_him(spec_overrides=None):
    spec = tasks.make("cartpole_balance_hist", 1, overrides={"history_len": 3, "history_extrinsics": False,
                                                             "history_exclude": (3, 4), **(spec_overrides or {})}).spec
    cfg = apply_overrides(him_ppo.Config(), {"actor_hidden": (8,), "critic_hidden": (8,), "velocity_cols": (3, 4),
                                             "estimator_hidden": (8,), "target_hidden": (8,), "latent_dim": 4,
                                             "num_prototypes": 5})
    return spec, cfg


def test_him_gradients_stay_in_their_part():
    from unilab_jax.algos.ppo import ppo
    from unilab_jax.core import normalizer

    spec, cfg = _small_him()
    xp = shim.get("jax")
    np_ = shim.get("numpy")
    params = nets.convert(him_ppo.init_params(np_.random.key(0), spec, cfg, np_), xp)  # eager jax init compiles a lot
    rng = np.random.default_rng(0)
    n = 16
    mb = {"obs": rng.normal(size=(n, spec.obs_dim)), "critic_obs": rng.normal(size=(n, spec.critic_obs_dim)),
          "next_critic_obs": rng.normal(size=(n, spec.critic_obs_dim)), "action": rng.normal(size=(n, 1)),
          "log_prob": rng.normal(size=n), "mean": rng.normal(size=(n, 1)), "log_std": np.zeros((n, 1)),
          "advantages": rng.normal(size=n), "returns": rng.normal(size=n), "values": rng.normal(size=n)}
    mb = {k: jax.numpy.asarray(v, jax.numpy.float32) for k, v in mb.items()}
    on, cn = normalizer.stats_init(spec.obs_dim, xp), normalizer.stats_init(spec.critic_obs_dim, xp)
    g_ppo = jax.jit(jax.grad(lambda p: ppo.loss(p, on, cn, mb, cfg, actor=him_ppo.actor)[0]))(params)
    g_est = jax.jit(jax.grad(lambda p: him_ppo.estimator_loss(p["estimator"], on, cn, mb, cfg)[0]))(params)
    norm = lambda tree: float(sum(jax.numpy.sum(jax.numpy.abs(x)) for x in jax.tree_util.tree_leaves(tree)))
    assert norm(g_ppo["estimator"]) == 0.0 and norm(g_ppo["actor"]) > 0.0  # the policy does not shape the estimator
    assert norm(g_est["actor"]) + norm(g_est["critic"]) == 0.0 and norm(g_est["estimator"]["encoder"]) > 0.0
    w = nets.to_numpy(him_ppo.policy_weights(params, on))
    action, extras = him_ppo.act(w, np.asarray(mb["obs"]), np.zeros((n, 1), np.float32), True)
    assert action.shape == (n, 1) and set(extras) == set(him_ppo.extras(1))


def test_teacher_reads_the_last_frame_whatever_the_history_length():
    xp = shim.get("numpy")
    spec1 = tasks.make("cartpole_balance_hist", 1, overrides={**DR_TASK, "history_len": 1}).spec
    cfg = apply_overrides(hora_teacher.Config(), {"actor_hidden": (8,), "critic_hidden": (8,), "encoder_hidden": (8,)})
    from unilab_jax.algos.ppo import ppo
    from unilab_jax.core import normalizer

    rng = np.random.default_rng(0)
    params = ppo.init_params(xp.random.key(0), spec1.frame_dim + cfg.z_dim, spec1.critic_obs_dim, 1, cfg, xp)
    params["encoder"] = nets.init(xp.random.key(1), [spec1.privileged_dim, 8, cfg.z_dim], xp)
    stats = normalizer.RunningStats(rng.normal(size=spec1.obs_dim).astype(np.float32),
                                    rng.uniform(0.5, 2, size=spec1.obs_dim).astype(np.float32), np.float32(10))
    w = {"actor": params["actor"], "encoder": params["encoder"], "log_std": params["log_std"], "obs_norm": stats}
    short = rng.normal(size=(4, spec1.obs_dim)).astype(np.float32)
    long = np.concatenate([rng.normal(size=(4, 5 * spec1.frame_dim)), short], axis=1).astype(np.float32)
    np.testing.assert_allclose(hora_teacher.act(w, long, None, True)[0], hora_teacher.act(w, short, None, True)[0])


@pytest.mark.parametrize("module,overrides,message", [
    (hora_teacher, {"history_extrinsics": False}, "history_extrinsics=True"),
    (him_ppo, {"history_extrinsics": True}, "history_extrinsics=False"),
])
def test_learners_refuse_the_wrong_task_variant(module, overrides, message):
    spec = tasks.make("cartpole_balance_hist", 1, overrides=overrides).spec
    cfg = apply_overrides(module.Config(), {"velocity_cols": (3,)} if module is him_ppo else {})
    with pytest.raises(ValueError, match=message):
        module.make_learner("jax", cfg, spec)
    with pytest.raises(ValueError, match="jax"):
        module.check_run("mlx", tasks.default_config("cartpole_balance_hist"), cfg)
