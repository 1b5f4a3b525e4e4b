"""FastSAC on the Unitree G1 (29 DoF, 15 actions) rough walk (``g1_walk_rough``: the terrain grid and its
curriculum), sized for a 16-core + H100 machine.

    python experiments/fastsac_g1_rough.py --num_workers=16 --envs_per_worker=64 --logdir=runs/fastsac_g1_rough

The flat recipe (``fastsac_g1.py``: FastSAC's humanoid recipe with a C51 support sized for G1's returns) on the
rough task: the critic sees the height scan, the actor is blind (``--task_config=perceptive=True`` lets it see
too); motor strength and a 0-1 step action latency are randomised per env (pushes stay off, as on flat ground:
``--task_config=push_interval_s=5`` turns them on). Training logs ``episode/terrain_level`` and the level
histogram; evaluations report the walking numbers overall and per terrain type, and ``eval/rough_terrain_walking``
(docs/TERRAIN.md). Not tuned: no run of it has been measured yet.
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.FASTSAC_G1

if __name__ == "__main__":
    run_experiment(**recipes.get("fastsac_g1_rough").kwargs)
