"""SAC on Gymnasium's Pendulum-v1 (``--task=gym:ENV_ID``): a standard benchmark through the same runtime.

    python experiments/sac_pendulum.py --logdir=runs/sac_pendulum

Sized for the 2-core dev VM (2 workers x 32 envs stepping Gymnasium's SyncVectorEnv, the learner
sharing the cores). A random policy scores about -1200 per 200-step episode, a swung-up, balanced
pendulum -150 to -200. Measured there at 20k env steps (~4.5k gradient steps, ``utd`` 0.25 with fast target
networks, tau 0.02), seeds 0-5: evaluation returns -143 to -167, ~7 s of CPU (tests/test_gym_training.py).
"""

from unilab_jax.apps.cli import run_experiment

RECIPE = {"actor_hidden": (64, 64), "critic_hidden": (64, 64), "batch_size": 256, "updates_per_call": 32,
          "publish_every": 32, "utd": 0.25, "learning_starts": 2_000, "replay_capacity": 200_000,
          "actor_learning_rate": 1e-3, "critic_learning_rate": 1e-3, "alpha_learning_rate": 1e-3,
          "gamma": 0.98, "tau": 0.02}

if __name__ == "__main__":
    run_experiment(algo="sac", task="gym:Pendulum-v1", recipe=RECIPE, default_total_steps=30_000)
