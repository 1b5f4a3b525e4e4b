"""FastSAC on Go1 joystick rough (``go1_joystick_rough``: the terrain grid and its curriculum), sized for a
16-core + H100 machine.

    python experiments/fastsac_go1_rough.py --num_workers=16 --envs_per_worker=64 --logdir=runs/fastsac_go1_rough

The flat recipe (``fastsac_go1.py``: FastSAC's defaults with a C51 support sized for Go1's returns) on the rough
task; the critic sees the height scan, the actor is blind (``--task_config=perceptive=True`` lets it see too).
Training logs the curriculum as ``episode/terrain_level`` and ``episode/terrain_level_<k>``; evaluations run on
the upper half of the levels and report the walking numbers overall and per terrain type (docs/TERRAIN.md).
Not tuned: no run of it has been measured yet.
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.FASTSAC_GO1

if __name__ == "__main__":
    run_experiment(**recipes.get("fastsac_go1_rough").kwargs)
