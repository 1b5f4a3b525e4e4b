"""HIM-PPO on Go1 joystick flat: PPO whose policy sees 6 frames through a hybrid internal model that
estimates the base velocity (removed from the frames) and a contrastive latent.

    python experiments/him_ppo_go1.py --num_workers=15 --envs_per_worker=128 --eval_every=2000000 \\
        --logdir=runs/him_ppo_go1
"""

from ppo_go1 import RECIPE as PPO_RECIPE

from unilab_jax.apps.cli import run_experiment
from unilab_jax.sizing import SizedFor

# Frames: Go1's 48-dim observation without the measured body-frame linear velocity (columns 0-2), as
# in HIMLoco, whose robots do not measure it; the estimator's target is the clean body-frame linear
# velocity of the successor state, critic columns 57-59 (tasks/go1_math.py observe).
TASK_RECIPE = {"history_len": 6, "history_extrinsics": False, "history_exclude": (0, 1, 2)}
RECIPE = {**PPO_RECIPE, "velocity_cols": (57, 58, 59)}

if __name__ == "__main__":
    run_experiment(algo="him_ppo", task="go1_joystick_flat_hist", recipe=RECIPE, task_recipe=TASK_RECIPE,
                   default_total_steps=100_000_000,
                   sized_for=SizedFor("a 16-core H100 host", 15, 128))
