"""TD3 on Go1 joystick flat, FastTD3-style, sized for a 16-core + H100 machine.

    python experiments/td3_go1.py --num_workers=16 --envs_per_worker=64 --logdir=runs/td3_go1

FastTD3's Go1 setting (Seo et al. 2025, arXiv:2505.22642): 1024 envs, 8 gradient steps per vectorised
env step (``utd`` 8/1024 per transition), gamma 0.97, fast targets (tau 0.1), AdamW weight decay 0.1,
target smoothing 0.2, 1024-512-256 critics / 512-256-128 actor; our batch is 8192 (theirs 32768, a
critic ensemble of two on one GPU). Exploration std 0.2: the low end of FastTD3's per-env Go1 range
[0.2, 0.8] -- with Go1's clipped reward large noise keeps every step's reward at 0 (ppo_go1.py).
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.TD3_GO1

if __name__ == "__main__":
    run_experiment(**recipes.get("td3_go1").kwargs)
