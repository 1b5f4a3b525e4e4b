"""PPO with a privileged critic on Allegro in-hand rotation (tasks/allegro_rotate.py, HORA's task).

The policy sees one proprioceptive frame (joint angles, velocities, previous targets) and the object's
state and parameters (the task's extrinsics with its quaternion and velocities); the critic too.
Evaluations log eval/rotation_rate (rad/s) and eval/time_to_fall (fraction of the 400-step episode)
beside eval/return.

    python experiments/ppo_allegro_rotate.py --num_workers=15 --envs_per_worker=64 --eval_every=2000000 \\
        --logdir=runs/ppo_allegro
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.PPO_ALLEGRO_ROTATE
TASK_RECIPE = recipes.PPO_ALLEGRO_ROTATE_TASK

if __name__ == "__main__":
    run_experiment(**recipes.get("ppo_allegro_rotate").kwargs)
