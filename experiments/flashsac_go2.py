"""FlashSAC on Unitree Go2 joystick flat, sized for a 16-core + H100 machine.

    python experiments/flashsac_go2.py --num_workers=16 --envs_per_worker=64 --logdir=runs/flashsac_go2

FlashSAC: 2 gradient steps per vectorised step of 1024 envs (``utd`` 2/1024 per transition), batch
8192, norm-bounded networks, gradient clipping at 1, exploration noise held 4 control steps, gamma
0.99, fast targets (tau 0.1), temperature starting at 0.001.

Reward normalisation on (rewards / (rms(r) / (1 - gamma))): Go2's terms are x0.02 per step and dense
(a random policy already earns 0.10 per step, rms 0.10, range [-0.07, 0.23]), so the normalised
per-step reward is r / rms * 0.01 and normalised returns are ~mean(r) / rms(r): ~1 at first, up to
~2.5 once the policy earns ~0.2 per step, negative only for a policy that keeps collecting penalties.
[-2, 4] covers that with a 0.06 atom spacing (FlashSAC's default [-5, 5] would waste half its atoms).
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.FLASHSAC_GO2

if __name__ == "__main__":
    run_experiment(**recipes.get("flashsac_go2").kwargs)
