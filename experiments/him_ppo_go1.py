"""HIM-PPO on Go1 joystick flat: PPO whose policy sees 6 frames through a hybrid internal model that
estimates the base velocity (removed from the frames) and a contrastive latent.

    python experiments/him_ppo_go1.py --num_workers=15 --envs_per_worker=128 --eval_every=2000000 \\
        --logdir=runs/him_ppo_go1
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

TASK_RECIPE = recipes.HIM_PPO_GO1_TASK
RECIPE = recipes.HIM_PPO_GO1

if __name__ == "__main__":
    run_experiment(**recipes.get("him_ppo_go1").kwargs)
