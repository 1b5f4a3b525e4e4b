"""APPO on Go1 joystick flat: workers never wait for the learner; V-trace corrects policy lag.

    python experiments/appo_go1.py --num_workers=15 --envs_per_worker=128 --logdir=runs/appo_go1
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

if __name__ == "__main__":
    run_experiment(**recipes.get("appo_go1").kwargs)
