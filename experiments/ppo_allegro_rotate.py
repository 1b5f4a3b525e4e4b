"""PPO with a privileged critic on Allegro in-hand rotation (tasks/allegro_rotate.py, HORA's task).

The policy sees one proprioceptive frame (joint angles, velocities, previous targets) and the object's
state and parameters (the task's extrinsics with its quaternion and velocities); the critic too.
Evaluations log eval/rotation_rate (rad/s) and eval/time_to_fall (fraction of the 400-step episode)
beside eval/return.

    python experiments/ppo_allegro_rotate.py --num_workers=15 --envs_per_worker=64 --eval_every=2000000 \\
        --logdir=runs/ppo_allegro
"""

from unilab_jax.apps.cli import run_experiment

# HORA's PPO (rl_games): 512-256-128 ELU networks, gamma 0.99, lambda 0.95, 5 epochs, KL-adaptive learning
# rate, no entropy bonus, unit initial action std (the action scale 1/24 keeps that gentle). The networks,
# gamma, lambda, epochs and std are PPO's defaults; the recipe lists what differs.
RECIPE = {"horizon": 16, "learning_rate": 5e-3, "ent_coef": 0.0, "desired_kl": 0.02}

# Trained on the rotation and fall terms only: with HORA's penalty scales (the task's defaults), and with a
# tenth of them, PPO settled on a still hand within 0.6-1.5M steps and never rotated the object, while
# without them the rotation term rose from 0 to 0.03-0.04 per step by 2-2.5M steps (dev VM, README "In-hand
# rotation (Allegro)"). Put the penalties back with --task_config=scale_pose_diff=-0.3 etc.
# A privileged actor (the object's parameters, position, quaternion and velocities) whose reset targets press the
# fingers on the object (reset_press). Dev VM, 1024 samples per update, deterministic evaluations (rad/s) at
# 0.6M / 1.2M steps: seed 0 0.04 / 0.20 without the press, 0.14 / - with it; seed 1 0.01 / 0.04 without, 0.03 /
# 0.16 with it; seed 2 0.003 / 0.007 with it; the blind actor reached at most 0.10 in 2.5M steps (README
# "In-hand rotation (Allegro)").
TASK_RECIPE = {"scale_object_linvel": 0.0, "scale_pose_diff": 0.0, "scale_torque": 0.0, "scale_work": 0.0,
               "object_state_extrinsics": True, "actor_extrinsics": True, "reset_press": 0.25}

if __name__ == "__main__":
    run_experiment(algo="ppo", task="allegro_rotate", recipe=RECIPE, task_recipe=TASK_RECIPE,
                   default_total_steps=100_000_000)
