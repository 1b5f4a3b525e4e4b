"""State-based SAC Flow on pick-and-place through robot servers: ``sac_franka_pick.py`` with the flow policy.

    python experiments/sacflow_franka_pick.py --robots=sim:franka_emika_panda --speed=20 \\
        --total_steps=3000 --logdir=runs/sacflow_pick

Same robots, flags, task and SAC recipe as ``sac_franka_pick.py`` (so SAC Flow and SAC compare at equal
robot time); the actor is the gated K-step flow (``--config=flow_steps=K``, default 4) trained with
SAC's objective and automatic temperature (``unilab_jax/algos/offpolicy/sacflow.py``).
"""

from unilab_jax import recipes
from unilab_jax.apps.robot_cli import run_robot_experiment

if __name__ == "__main__":
    run_robot_experiment(**recipes.get("sacflow_franka_pick").kwargs)
