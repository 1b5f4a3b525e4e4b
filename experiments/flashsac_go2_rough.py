"""FlashSAC on Go2 joystick rough (``go2_joystick_rough``: the terrain grid and its curriculum), sized for a
16-core + H100 machine.

    python experiments/flashsac_go2_rough.py --num_workers=16 --envs_per_worker=64 --logdir=runs/flashsac_go2_rough

The flat recipe (``flashsac_go2.py``) on the rough task: the critic sees the height scan, the actor is blind
(``--task_config=perceptive=True`` lets it see too); motor strength and a 0-1 step action latency are
randomised per env. Training logs the curriculum as ``episode/terrain_level`` and ``episode/terrain_level_<k>``;
evaluations run on the upper half of the levels and report the walking numbers overall and per terrain type, and
``eval/rough_terrain_walking`` (docs/TERRAIN.md). Not tuned: no run of it has been measured yet.
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.FLASHSAC_GO2

if __name__ == "__main__":
    run_experiment(**recipes.get("flashsac_go2_rough").kwargs)
