"""SAC on Gymnasium's Pendulum-v1 (``--task=gym:ENV_ID``): a standard benchmark through the same runtime.

    python experiments/sac_pendulum.py --logdir=runs/sac_pendulum

Sized for the 2-core dev VM (2 workers x 32 envs stepping Gymnasium's SyncVectorEnv, the learner
sharing the cores). A random policy scores about -1200 per 200-step episode, a swung-up, balanced
pendulum -150 to -200. Measured there at 20k env steps (~4.5k gradient steps, ``utd`` 0.25 with fast target
networks, tau 0.02), seeds 0-5: evaluation returns -143 to -167, ~7 s of CPU (tests/test_gym_training.py).
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.SAC_PENDULUM

if __name__ == "__main__":
    run_experiment(**recipes.get("sac_pendulum").kwargs)
