"""FastSAC on G1 whole-body motion tracking (``g1_track``), sized for a 16-core + H100 machine.

    python experiments/fastsac_g1_track.py --num_workers=15 --envs_per_worker=64 --logdir=runs/fastsac_g1_track

FastSAC's humanoid recipe as in ``fastsac_g1.py`` (batch 8192, 8 gradient steps per 1024 env steps, gamma
0.97, tau 0.1, C51 critics with LayerNorm, temperature from 0.001, AdamW weight decay 0.1), with the
support sized for this task's reward: 0.02 * (0.5 + 0.5 + 4 x 1.0) = 0.1 per step at perfect tracking,
minus the action-rate penalty (0.02 x 0.1 x |a - a_prev|^2, up to ~0.2 for tanh-squashed actions that
jump across their range on all 29 joints) and the joint-limit penalty. 0.97-discounted returns lie in
about [-3, 3.3]; [-3, 4] keeps a 0.07 atom spacing.
"""

from fastsac_go1 import RECIPE as GO1_RECIPE  # FastSAC's recipe; only the support differs

from unilab_jax.apps.cli import run_experiment
from unilab_jax.sizing import SizedFor

RECIPE = {**GO1_RECIPE, "v_min": -3.0, "v_max": 4.0}

if __name__ == "__main__":
    run_experiment(algo="fastsac", task="g1_track", recipe=RECIPE, default_total_steps=100_000_000,
                   sized_for=SizedFor("a 16-core H100 host", 15, 64))
