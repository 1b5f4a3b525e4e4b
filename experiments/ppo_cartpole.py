"""PPO on cart-pole balance: the quick demo (`make train`) and CI learning check.

    python experiments/ppo_cartpole.py --logdir=runs/ppo_cartpole

Sized for the 2-core dev VM: the flag defaults, 2 workers x 32 envs (``--num_workers=auto`` sizes it for
the machine instead).
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.PPO_CARTPOLE

if __name__ == "__main__":
    run_experiment(**recipes.get("ppo_cartpole").kwargs)
