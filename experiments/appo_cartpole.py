"""APPO on cart-pole balance: asynchronous workers, V-trace correction.

    python experiments/appo_cartpole.py --logdir=runs/appo_cartpole

Sized for the 2-core dev VM: the flag defaults, 2 workers x 32 envs.
"""

from ppo_cartpole import RECIPE  # same hyperparameters as PPO; only the sync mode and targets differ

from unilab_jax.apps.cli import run_experiment

if __name__ == "__main__":
    run_experiment(algo="appo", task="cartpole_balance", recipe=RECIPE, default_total_steps=200_000)
