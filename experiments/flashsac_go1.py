"""FlashSAC on Go1 joystick flat, sized for a 16-core + H100 machine.

    python experiments/flashsac_go1.py --num_workers=16 --envs_per_worker=64 --logdir=runs/flashsac_go1

Fewer, larger updates than FastSAC: 2 gradient steps per vectorised step of 1024 envs (``utd`` 2/1024
per transition), batch 8192, norm-bounded 512-wide critics, gradient clipping at 1, exploration noise
held 4 control steps (``flashsac.NOISE_HOLD_STEPS``), gamma 0.97 (Playground's Go1 horizon).

Reward normalisation is OFF here, and the support is in raw return units: Go1's reward is clipped >= 0
and starts near 0 (a random policy averages 0.0004 per step, rms 0.002) while a walking policy earns
~0.02-0.03. The normaliser divides by a running rms over all rewards seen so far, which lags such a
10x rise: normalised returns would reach ~10-15 and pile up on the edge of FlashSAC's [-5, 5] support.
Raw 0.97-discounted returns lie in [0, ~1]; [-0.5, 1.5] gives a 0.02 atom spacing. Temperature starts
at 0.001 and the initial policy std is ~0.2 per joint (small, as Go1's clipped reward needs). The networks,
update rate, batch and clipping are FlashSAC's defaults (``FlashSACConfig``); the recipe lists what differs.
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.FLASHSAC_GO1

if __name__ == "__main__":
    run_experiment(**recipes.get("flashsac_go1").kwargs)
