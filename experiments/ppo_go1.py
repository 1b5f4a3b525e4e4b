"""PPO on Go1 joystick flat (MuJoCo Playground parity task).

    python experiments/ppo_go1.py --num_workers=16 --envs_per_worker=64 --logdir=runs/ppo_go1

PPO's defaults (512-256-128 ELU networks, 24-step horizon, 5 epochs x 4 minibatches, lr 1e-3 with the
KL-adaptive rule, lambda 0.95, entropy 0.01) with Playground's gamma 0.97 and a small initial std.
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.PPO_GO1

if __name__ == "__main__":
    run_experiment(**recipes.get("ppo_go1").kwargs)
