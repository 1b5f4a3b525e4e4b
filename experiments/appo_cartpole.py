"""APPO on cart-pole balance: asynchronous workers, V-trace correction.

    python experiments/appo_cartpole.py --logdir=runs/appo_cartpole

Sized for the 2-core dev VM: the flag defaults, 2 workers x 32 envs.
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

if __name__ == "__main__":
    run_experiment(**recipes.get("appo_cartpole").kwargs)
