"""SAC on Go1 joystick flat (MuJoCo Playground parity task), sized for a 16-core + H100 machine.

    python experiments/sac_go1.py --num_workers=16 --envs_per_worker=64 --logdir=runs/sac_go1

1024 envs feed the replay ring; the learner takes 8 gradient steps per vectorised env step of those
1024 envs (``utd`` 8/1024 per transition, FastTD3's Go1 setting) on batches of 4096; gamma 0.97 as in
Playground; fast targets (tau 0.1, as FastTD3/FastSAC use with large batches). Go1's reward is
clipped >= 0 and at most ~0.03 per step, so Q values are O(1): the temperature starts at 0.001 (SAC's
usual 0.2 times an entropy of a few nats would outweigh the reward ~10x and drive the policy to
maximal noise). The initial policy std is exp(-1.5) = 0.22 per joint (the bounded log-std head at its
midpoint), below PPO's 0.37: large initial noise keeps every step's clipped reward at 0 and learning
never starts (bench/results/README.md).
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.SAC_GO1

if __name__ == "__main__":
    run_experiment(**recipes.get("sac_go1").kwargs)
