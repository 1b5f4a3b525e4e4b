"""PPO on Go1 joystick flat, GPU-resident: MJX physics and the learner in one jitted loop (the baseline).

    python experiments/ppo_go1_mjx.py --num_envs=8192 --eval_every=5000000 --logdir=runs/ppo_go1_mjx

Same PPO (loss, networks, learner update) and hyperparameters as ``ppo_go1.py`` on the CPU runtime, with
MuJoCo Playground's data regime for its Go1 PPO: 8192 envs, unrolls of 20 steps, 4 epochs x 32 minibatches
per iteration (163,840 transitions; 8192 envs: ``run_mjx_experiment``'s default).
"""

from unilab_jax import recipes
from unilab_jax.apps.mjx_cli import run_mjx_experiment

MJX_RECIPE = recipes.PPO_GO1_MJX

if __name__ == "__main__":
    run_mjx_experiment(**recipes.get("ppo_go1_mjx").kwargs)
