"""APPO on Go1 joystick flat: workers never wait for the learner; V-trace corrects policy lag.

    python experiments/appo_go1.py --num_workers=15 --envs_per_worker=128 --logdir=runs/appo_go1
"""

from ppo_go1 import RECIPE  # same hyperparameters as PPO; only the sync mode and targets differ

from unilab_jax.apps.cli import run_experiment
from unilab_jax.sizing import SizedFor

if __name__ == "__main__":
    run_experiment(algo="appo", task="go1_joystick_flat", recipe=RECIPE, default_total_steps=100_000_000,
                   sized_for=SizedFor("a 16-core H100 host", 15, 128))
