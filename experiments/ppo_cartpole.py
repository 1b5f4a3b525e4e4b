"""PPO on cart-pole balance: the quick demo (`make train`) and CI learning check.

    python experiments/ppo_cartpole.py --logdir=runs/ppo_cartpole

Sized for the 2-core dev VM: the flag defaults, 2 workers x 32 envs (``--num_workers=auto`` sizes it for
the machine instead).
"""

from unilab_jax.apps.cli import run_experiment

RECIPE = {"actor_hidden": (64, 64), "critic_hidden": (64, 64), "horizon": 32, "ent_coef": 0.0, "gamma": 0.98}

if __name__ == "__main__":
    run_experiment(algo="ppo", task="cartpole_balance", recipe=RECIPE, default_total_steps=200_000)
