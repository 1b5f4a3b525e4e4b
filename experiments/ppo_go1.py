"""PPO on Go1 joystick flat (MuJoCo Playground parity task).

    python experiments/ppo_go1.py --num_workers=16 --envs_per_worker=64 --logdir=runs/ppo_go1

PPO's defaults (512-256-128 ELU networks, 24-step horizon, 5 epochs x 4 minibatches, lr 1e-3 with the
KL-adaptive rule, lambda 0.95, entropy 0.01) with Playground's gamma 0.97 and a small initial std.
"""

from unilab_jax.apps.cli import run_experiment
from unilab_jax.sizing import SizedFor

RECIPE = {"gamma": 0.97,
          # Small initial exploration noise (std 0.37): with the clipped Playground reward, std 1 makes
          # nearly every step's reward 0 and learning never starts (measured: bench/results/README.md).
          "init_log_std": -1.0}

if __name__ == "__main__":
    run_experiment(algo="ppo", task="go1_joystick_flat", recipe=RECIPE, default_total_steps=100_000_000,
                   sized_for=SizedFor("a 16-core H100 host", 16, 64))
