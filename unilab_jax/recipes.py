"""The experiments' recipes as data: what each script of ``experiments/`` runs (its algorithm, task, hyperparameters
that differ from the defaults, step budget and the machine it was sized for), importable without running it.

    from unilab_jax import recipes
    r = recipes.get("fastsac_go1")
    r.algo, r.task, r.recipe, r.task_recipe, r.total_steps   # "fastsac", "go1_joystick_flat", {...}, {}, 50_000_000
    unilab_jax.train(**r.train_args(), logdir="runs/fastsac_go1", num_workers=2)

``experiments/<name>.py`` calls its launcher (``Recipe.launcher``: ``apps.cli.run_experiment``, ``apps.mjx_cli.
run_mjx_experiment``, ``apps.robot_cli.run_robot_experiment``, ``apps.hora_cli.run_hora``) with ``Recipe.kwargs``; the
scripts keep the docs and the measurements behind each recipe, the comments here the reasons for single entries.
Each dict lists only what differs from the defaults it overrides (tests/test_recipes.py). Pure data: importing this
module imports no algorithm, task or backend.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from unilab_jax.sizing import SizedFor

# The manipulation recipe of sac_franka_peg, rlpd_franka_peg and rlpd_franka_pick: small networks and utd 4 fit a
# 2-core CPU (``--config utd=20``: the RLPD paper's ratio, for a GPU); the policy sees the object state. A small
# initial temperature: success ends an episode, and the entropy bonus carried in the soft target (alpha x entropy
# / (1 - gamma), ~24 at RLPD's init_alpha 1 on peg insertion) outweighed the success bonus, so learners avoided
# finishing.
MANIPULATION_RECIPE = {"actor_hidden": (128, 128), "critic_hidden": (128, 128), "batch_size": 128,
                       "updates_per_call": 16, "publish_every": 16, "utd": 4.0, "learning_starts": 300,
                       "replay_capacity": 200_000, "gamma": 0.95, "init_alpha": 0.01}

# ppo_cartpole.py
PPO_CARTPOLE = {"actor_hidden": (64, 64), "critic_hidden": (64, 64), "horizon": 32, "ent_coef": 0.0, "gamma": 0.98}

# ppo_go1.py, ppo_go1_rough.py
PPO_GO1 = {"gamma": 0.97,
           # Small initial exploration noise (std 0.37): with the clipped Playground reward, std 1 makes
           # nearly every step's reward 0 and learning never starts (measured: bench/results/README.md).
           "init_log_std": -1.0}

# fastsac_go1.py, fastsac_go1_rough.py
FASTSAC_GO1 = {"v_min": -0.5, "v_max": 1.5}

# fastsac_go1.py: 12 gradient steps per 1024 transitions (FastSAC's default is 8): on the H100 machine the fused
# LayerNorm kernels let the learner keep this ratio, and Go1 walked by 85-120 s on 4 of 4 seeds (mean 97.7 s) against
# 102 s / not by 140 / not by 140 / 102 s at 8 (docs/perf/learner_scaling.md section 17; ``--utd_mode=free``). Walking
# took 5-7M env steps at either ratio, so where the learner is the limit (a smaller GPU, ``--utd_mode=hold``) 8 may
# walk sooner: ``--config utd=0.0078125``.
FASTSAC_GO1_FLAT = {**FASTSAC_GO1, "utd": 12 / 1024}

# fastsac_g1.py, fastsac_g1_rough.py
FASTSAC_G1 = {**FASTSAC_GO1, "v_min": -2.0, "v_max": 3.0}

# fastsac_g1_track.py
FASTSAC_G1_TRACK = {**FASTSAC_GO1, "v_min": -3.0, "v_max": 4.0}

# flashsac_go1.py
FLASHSAC_GO1 = {"gamma": 0.97, "init_alpha": 0.001, "normalize_rewards": False, "v_min": -0.5, "v_max": 1.5}

# flashsac_go2.py, flashsac_go2_rough.py
FLASHSAC_GO2 = {**FLASHSAC_GO1, "gamma": 0.99, "normalize_rewards": True, "v_min": -2.0, "v_max": 4.0}

# him_ppo_go1.py
# Frames: Go1's 48-dim observation without the measured body-frame linear velocity (columns 0-2), as
# in HIMLoco, whose robots do not measure it; the estimator's target is the clean body-frame linear
# velocity of the successor state, critic columns 57-59 (tasks/go1_math.py observe).
HIM_PPO_GO1_TASK = {"history_len": 6, "history_extrinsics": False, "history_exclude": (0, 1, 2)}
HIM_PPO_GO1 = {**PPO_GO1, "velocity_cols": (57, 58, 59)}

# ppo_allegro_rotate.py
# HORA's PPO (rl_games): 512-256-128 ELU networks, gamma 0.99, lambda 0.95, 5 epochs, KL-adaptive learning
# rate, no entropy bonus, unit initial action std (the action scale 1/24 keeps that gentle). The networks,
# gamma, lambda, epochs and std are PPO's defaults; the recipe lists what differs.
PPO_ALLEGRO_ROTATE = {"horizon": 16, "learning_rate": 5e-3, "ent_coef": 0.0, "desired_kl": 0.02}
# Trained on the rotation and fall terms only: with HORA's penalty scales (the task's defaults), and with a
# tenth of them, PPO settled on a still hand within 0.6-1.5M steps and never rotated the object, while
# without them the rotation term rose from 0 to 0.03-0.04 per step by 2-2.5M steps (dev VM, docs/RESULTS.md "In-hand
# rotation (Allegro)"). Put the penalties back with --task_config=scale_pose_diff=-0.3 etc.
# A privileged actor (the object's parameters, position, quaternion and velocities) whose reset targets press the
# fingers on the object (reset_press). Dev VM, 1024 samples per update, deterministic evaluations (rad/s) at
# 0.6M / 1.2M steps: seed 0 0.04 / 0.20 without the press, 0.14 / - with it; seed 1 0.01 / 0.04 without, 0.03 /
# 0.16 with it; seed 2 0.003 / 0.007 with it; the blind actor reached at most 0.10 in 2.5M steps (docs/RESULTS.md
# "In-hand rotation (Allegro)").
PPO_ALLEGRO_ROTATE_TASK = {"scale_object_linvel": 0.0, "scale_pose_diff": 0.0, "scale_torque": 0.0, "scale_work": 0.0,
                           "object_state_extrinsics": True, "actor_extrinsics": True, "reset_press": 0.25}

# hora_allegro.py
# Rotation and fall terms only and the object's state in the extrinsics, as the PPO recipe; but the frames stay
# proprioceptive (the student's history must not hold the extrinsics): the teacher sees them through z only
# (the history variant appends them after the frames: history_extrinsics, its default).
HORA_ALLEGRO_TASK = {**PPO_ALLEGRO_ROTATE_TASK, "actor_extrinsics": False}
HORA_ALLEGRO_STUDENT = {"horizon": 16}  # else hora_student's defaults: lr 1e-3, 2 epochs x 4 minibatches

# hora_go1.py
# Go1's extrinsics (tasks/go1_joystick.py; the history variant appends them after the frames by default): floor
# friction, joint friction loss, armature, torso COM, link masses, torso mass, default-pose offset and (enabled
# here, +-10%) motor strength: 66 numbers.
HORA_GO1_TASK = {"dr_motor_strength": (0.9, 1.1)}
HORA_GO1_STUDENT = {}  # hora_student's defaults: 24-step horizon, lr 1e-3, 2 epochs x 4 minibatches

# ppo_g1_track.py
PPO_G1_TRACK = {"ent_coef": 0.005, "init_log_std": -1.0}

# ppo_go1_mjx.py
PPO_GO1_MJX = {**PPO_GO1, "horizon": 20, "num_epochs": 4, "num_minibatches": 32}

# sac_cartpole.py
SAC_CARTPOLE = {"actor_hidden": (64, 64), "critic_hidden": (64, 64), "batch_size": 256, "updates_per_call": 32,
                "publish_every": 32, "utd": 0.0125, "actor_learning_rate": 1e-3, "critic_learning_rate": 1e-3,
                "alpha_learning_rate": 1e-3, "gamma": 0.98, "tau": 0.02}

# sac_franka_pick.py
SAC_FRANKA_PICK = {"actor_hidden": (64, 64), "critic_hidden": (64, 64), "batch_size": 128, "utd": 0.5,
                   "learning_starts": 500, "replay_capacity": 200_000, "actor_learning_rate": 1e-3,
                   "critic_learning_rate": 1e-3, "alpha_learning_rate": 1e-3, "gamma": 0.95}

# sac_go1.py
SAC_GO1 = {"actor_hidden": (512, 256, 128), "critic_hidden": (1024, 512, 256), "batch_size": 4096,
           "utd": 8 / 1024, "replay_capacity": 2_097_152, "learning_starts": 16_384, "gamma": 0.97, "tau": 0.1,
           "init_alpha": 0.001}

# sac_mujoco_gym.py
SAC_MUJOCO_GYM = {"batch_size": 256, "learning_starts": 10_000}

# sac_pendulum.py
SAC_PENDULUM = {"actor_hidden": (64, 64), "critic_hidden": (64, 64), "batch_size": 256, "updates_per_call": 32,
                "publish_every": 32, "utd": 0.25, "learning_starts": 2_000, "replay_capacity": 200_000,
                "actor_learning_rate": 1e-3, "critic_learning_rate": 1e-3, "alpha_learning_rate": 1e-3,
                "gamma": 0.98, "tau": 0.02}

# td3_cartpole.py
TD3_CARTPOLE = {"actor_hidden": (64, 64), "critic_hidden": (64, 64), "batch_size": 256, "updates_per_call": 32,
                "publish_every": 32, "utd": 0.015, "actor_learning_rate": 1e-4, "critic_learning_rate": 1e-3,
                "gamma": 0.98, "tau": 0.02}

# td3_go1.py
TD3_GO1 = {"actor_hidden": (512, 256, 128), "critic_hidden": (1024, 512, 256), "batch_size": 8192,
           "utd": 8 / 1024, "replay_capacity": 2_097_152, "learning_starts": 16_384, "gamma": 0.97, "tau": 0.1,
           "explore_std": 0.2, "weight_decay": 0.1}


# The step budget of a launcher whose script gives none (the launchers' own defaults).
LAUNCHER_STEPS = {"run_experiment": 1_000_000, "run_mjx_experiment": 100_000_000}


@dataclasses.dataclass(frozen=True)
class Recipe:
    """One experiment script's run: ``launcher`` (the function of ``unilab_jax.apps`` the script calls) and
    ``kwargs`` (exactly what it passes); the properties read the common parts."""

    name: str
    launcher: str
    kwargs: Mapping[str, Any]

    @property
    def algo(self) -> str:
        """The registered algorithm ("hora" for HORA's two stages: ``hora_teacher``, then ``hora_student``)."""
        return self.kwargs.get("algo", "hora")

    @property
    def task(self) -> str:
        return self.kwargs["task"]

    @property
    def recipe(self) -> dict[str, Any]:
        """Algorithm config overrides (HORA: the teacher's; ``kwargs["student_recipe"]`` the student's)."""
        return dict(self.kwargs.get("recipe", self.kwargs.get("teacher_recipe", {})))

    @property
    def task_recipe(self) -> dict[str, Any]:
        return dict(self.kwargs.get("task_recipe", {}))

    @property
    def total_steps(self) -> int:
        """Env steps the script trains for without --total_steps (HORA: the teacher stage's)."""
        if self.launcher == "run_hora":
            return self.kwargs["default_teacher_steps"]
        return self.kwargs.get("default_total_steps", LAUNCHER_STEPS.get(self.launcher, 0))

    @property
    def sized_for(self) -> SizedFor | None:
        """The machine the recipe was tuned on (None: the 2-core dev VM's 2 workers x 32 envs)."""
        return self.kwargs.get("sized_for")

    def train_args(self) -> dict[str, Any]:
        """``unilab_jax.train``'s arguments for this recipe (algo, task, config, task_config, total_steps); only for
        recipes of the CPU-worker trainer (``run_experiment``): the MJX, robot and HORA runs have their commands."""
        if self.launcher != "run_experiment":
            raise ValueError(f"recipe {self.name!r} runs through {self.launcher} (experiments/{self.name}.py), "
                             "not unilab_jax.train")
        return {"algo": self.algo, "task": self.task, "config": self.recipe, "task_config": self.task_recipe,
                "total_steps": self.total_steps}


_RECIPES = {r.name: r for r in (
    Recipe("ppo_cartpole", "run_experiment", dict(
        algo="ppo", task="cartpole_balance", recipe=PPO_CARTPOLE, default_total_steps=200_000)),
    Recipe("appo_cartpole", "run_experiment", dict(
        algo="appo", task="cartpole_balance", recipe=PPO_CARTPOLE, default_total_steps=200_000)),
    Recipe("ppo_go1", "run_experiment", dict(
        algo="ppo", task="go1_joystick_flat", recipe=PPO_GO1, default_total_steps=100_000_000,
        sized_for=SizedFor("a 16-core H100 host", 16, 64))),
    Recipe("ppo_go1_rough", "run_experiment", dict(
        algo="ppo", task="go1_joystick_rough", recipe=PPO_GO1, default_total_steps=200_000_000,
        sized_for=SizedFor("a 16-core H100 host", 16, 64))),
    Recipe("appo_go1", "run_experiment", dict(
        algo="appo", task="go1_joystick_flat", recipe=PPO_GO1, default_total_steps=100_000_000,
        sized_for=SizedFor("a 16-core H100 host", 15, 128))),
    Recipe("fastsac_go1", "run_experiment", dict(
        algo="fastsac", task="go1_joystick_flat", recipe=FASTSAC_GO1_FLAT, default_total_steps=50_000_000,
        sized_for=SizedFor("a 16-core H100 host", 16, 64))),
    Recipe("fastsac_go1_rough", "run_experiment", dict(
        algo="fastsac", task="go1_joystick_rough", recipe=FASTSAC_GO1, default_total_steps=100_000_000,
        sized_for=SizedFor("a 16-core H100 host", 16, 64))),
    Recipe("fastsac_g1", "run_experiment", dict(
        algo="fastsac", task="g1_walk_flat", recipe=FASTSAC_G1, default_total_steps=100_000_000,
        sized_for=SizedFor("a 16-core H100 host", 16, 64))),
    Recipe("fastsac_g1_rough", "run_experiment", dict(
        algo="fastsac", task="g1_walk_rough", recipe=FASTSAC_G1, default_total_steps=200_000_000,
        sized_for=SizedFor("a 16-core H100 host", 16, 64))),
    Recipe("fastsac_g1_track", "run_experiment", dict(
        algo="fastsac", task="g1_track", recipe=FASTSAC_G1_TRACK, default_total_steps=100_000_000,
        sized_for=SizedFor("a 16-core H100 host", 15, 64))),
    Recipe("fastsac_go1_mjx", "run_mjx_experiment", dict(
        algo="fastsac", task="go1_joystick_flat", recipe=FASTSAC_GO1, default_total_steps=50_000_000,
        default_num_envs=1024, default_iterations_per_call=50)),
    Recipe("flashsac_go1", "run_experiment", dict(
        algo="flashsac", task="go1_joystick_flat", recipe=FLASHSAC_GO1, default_total_steps=50_000_000,
        sized_for=SizedFor("a 16-core H100 host", 16, 64))),
    Recipe("flashsac_go2", "run_experiment", dict(
        algo="flashsac", task="go2_joystick_flat", recipe=FLASHSAC_GO2, default_total_steps=100_000_000,
        sized_for=SizedFor("a 16-core H100 host", 16, 64))),
    Recipe("flashsac_go2_rough", "run_experiment", dict(
        algo="flashsac", task="go2_joystick_rough", recipe=FLASHSAC_GO2, default_total_steps=200_000_000,
        sized_for=SizedFor("a 16-core H100 host", 16, 64))),
    Recipe("him_ppo_go1", "run_experiment", dict(
        algo="him_ppo", task="go1_joystick_flat_hist", recipe=HIM_PPO_GO1, task_recipe=HIM_PPO_GO1_TASK,
        default_total_steps=100_000_000, sized_for=SizedFor("a 16-core H100 host", 15, 128))),
    Recipe("ppo_allegro_rotate", "run_experiment", dict(
        algo="ppo", task="allegro_rotate", recipe=PPO_ALLEGRO_ROTATE, task_recipe=PPO_ALLEGRO_ROTATE_TASK,
        default_total_steps=100_000_000)),
    Recipe("hora_allegro", "run_hora", dict(
        task="allegro_rotate_hist", teacher_recipe=PPO_ALLEGRO_ROTATE, student_recipe=HORA_ALLEGRO_STUDENT,
        task_recipe=HORA_ALLEGRO_TASK, default_teacher_steps=60_000_000, default_student_steps=10_000_000,
        compare_metric="rotation_rate")),
    Recipe("hora_go1", "run_hora", dict(
        task="go1_joystick_flat_hist", teacher_recipe=PPO_GO1, student_recipe=HORA_GO1_STUDENT,
        task_recipe=HORA_GO1_TASK, default_teacher_steps=40_000_000, default_student_steps=10_000_000)),
    Recipe("ppo_g1_track", "run_experiment", dict(
        algo="ppo", task="g1_track", recipe=PPO_G1_TRACK, default_total_steps=100_000_000,
        sized_for=SizedFor("a 16-core H100 host", 15, 128))),
    Recipe("ppo_go1_mjx", "run_mjx_experiment", dict(
        algo="ppo", task="go1_joystick_flat", recipe=PPO_GO1_MJX, default_total_steps=200_000_000)),
    Recipe("rlpd_franka_peg", "run_robot_experiment", dict(
        algo="rlpd", task="robot_peg_insertion", recipe=MANIPULATION_RECIPE, default_total_steps=36_000,
        observation="images", dense_reward=False)),
    Recipe("rlpd_franka_pick", "run_robot_experiment", dict(
        algo="rlpd", task="robot_pick_place", recipe=MANIPULATION_RECIPE, default_total_steps=36_000,
        observation="images", dense_reward=False)),
    Recipe("sac_cartpole", "run_experiment", dict(
        algo="sac", task="cartpole_balance", recipe=SAC_CARTPOLE)),
    Recipe("sac_franka_peg", "run_robot_experiment", dict(
        algo="sac", task="robot_peg_insertion", recipe=MANIPULATION_RECIPE, default_total_steps=36_000,
        observation="images", dense_reward=False)),
    Recipe("sac_franka_pick", "run_robot_experiment", dict(
        algo="sac", task="robot_pick_place", recipe=SAC_FRANKA_PICK, default_total_steps=50_000)),
    Recipe("sac_go1", "run_experiment", dict(
        algo="sac", task="go1_joystick_flat", recipe=SAC_GO1, default_total_steps=50_000_000,
        sized_for=SizedFor("a 16-core H100 host", 16, 64))),
    Recipe("sac_mujoco_gym", "run_experiment", dict(
        algo="sac", task="gym:HalfCheetah-v5", recipe=SAC_MUJOCO_GYM)),
    Recipe("sac_pendulum", "run_experiment", dict(
        algo="sac", task="gym:Pendulum-v1", recipe=SAC_PENDULUM, default_total_steps=30_000)),
    Recipe("sacflow_franka_pick", "run_robot_experiment", dict(
        algo="sacflow", task="robot_pick_place", recipe=SAC_FRANKA_PICK, default_total_steps=50_000)),
    Recipe("td3_cartpole", "run_experiment", dict(
        algo="td3", task="cartpole_balance", recipe=TD3_CARTPOLE)),
    Recipe("td3_go1", "run_experiment", dict(
        algo="td3", task="go1_joystick_flat", recipe=TD3_GO1, default_total_steps=50_000_000,
        sized_for=SizedFor("a 16-core H100 host", 16, 64))),
)}


def names() -> list[str]:
    """The recipes, by script name (``experiments/<name>.py``)."""
    return sorted(_RECIPES)


def get(name: str) -> Recipe:
    """The recipe of ``experiments/<name>.py`` (``.py`` may be given)."""
    key = name.removesuffix(".py")
    if key not in _RECIPES:
        raise ValueError(f"unknown recipe {name!r}; recipes: {names()}")
    return _RECIPES[key]
