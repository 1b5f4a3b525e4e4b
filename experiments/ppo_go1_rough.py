"""PPO on Go1 joystick rough (``go1_joystick_rough``: the terrain grid and its curriculum).

    python experiments/ppo_go1_rough.py --num_workers=16 --envs_per_worker=64 --logdir=runs/ppo_go1_rough

The flat recipe (``ppo_go1.py``) on the rough task; the critic sees the height scan, the actor is blind
(``--task_config=perceptive=True`` lets it see too). Not tuned: no run of it has been measured yet.
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.PPO_GO1

if __name__ == "__main__":
    run_experiment(**recipes.get("ppo_go1_rough").kwargs)
