"""SAC on Gymnasium's MuJoCo benchmarks (``gym:HalfCheetah-v5`` by default; ``--task=gym:Hopper-v5``,
``gym:Walker2d-v5``, ``gym:Ant-v5``, ``gym:Humanoid-v5`` ...), with the hyperparameters of the SAC paper
(Haarnoja et al. 2018: 256-256 networks, lr 3e-4, batch 256, gamma 0.99, tau 0.005, one gradient step per
transition, learned temperature); learning starts after 10k transitions. SAC's defaults but for the batch and
the start of learning.

    python experiments/sac_mujoco_gym.py --num_workers=2 --envs_per_worker=4 --logdir=runs/sac_halfcheetah

Sized for one GPU with a few cores: one gradient step per transition makes the learner the bottleneck, so
few environments suffice (``--utd_mode=hold`` holds the ratio on any machine). Not run to convergence here.
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.SAC_MUJOCO_GYM

if __name__ == "__main__":
    run_experiment(**recipes.get("sac_mujoco_gym").kwargs)
