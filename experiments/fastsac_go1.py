"""FastSAC on Go1 joystick flat, sized for a 16-core + H100 machine.

    python experiments/fastsac_go1.py --num_workers=16 --envs_per_worker=64 --logdir=runs/fastsac_go1

FastTD3/FastSAC settings: 1024 envs, batch 8192, gamma 0.97, tau 0.1, C51 critics with 101 atoms and LayerNorm,
AdamW weight decay 0.1, temperature starting at 0.001. The support is sized for Go1's return scale, not FastTD3's
+-10: rewards are clipped >= 0 and at most ~0.03 per step, so 0.97-discounted returns lie in [0, ~1];
[-0.5, 1.5] keeps a 0.02 atom spacing (on +-10 the whole range would fall within ~5 atoms). Initial
policy std 0.22 per joint (see sac_go1.py): small, as Go1's clipped reward needs. These are FastSAC's defaults
(``FastSACConfig``); the recipe lists what differs: the support, and 12 gradient steps per vectorised env step
(``utd`` 12/1024 per transition; FastSAC's 8/1024 before the fused LayerNorm kernels let the learner keep more).
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.FASTSAC_GO1_FLAT

if __name__ == "__main__":
    run_experiment(**recipes.get("fastsac_go1").kwargs)
