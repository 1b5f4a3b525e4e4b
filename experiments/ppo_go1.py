"""PPO on Go1 joystick flat (MuJoCo Playground parity task).

    python experiments/ppo_go1.py --num_workers=16 --envs_per_worker=64 --logdir=runs/ppo_go1
"""

from unilab_jax.apps.cli import run_experiment
from unilab_jax.sizing import SizedFor

RECIPE = {"actor_hidden": (512, 256, 128), "critic_hidden": (512, 256, 128), "horizon": 24,
          "learning_rate": 1e-3, "num_epochs": 5, "num_minibatches": 4, "ent_coef": 0.01, "gamma": 0.97,
          "lam": 0.95, "desired_kl": 0.01,
          # Small initial exploration noise (std 0.37): with the clipped Playground reward, std 1 makes
          # nearly every step's reward 0 and learning never starts (measured: bench/results/README.md).
          "init_log_std": -1.0}

if __name__ == "__main__":
    run_experiment(algo="ppo", task="go1_joystick_flat", recipe=RECIPE, default_total_steps=100_000_000,
                   sized_for=SizedFor("a 16-core H100 host", 16, 64))
