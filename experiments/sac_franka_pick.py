"""State-based SAC on pick-and-place through robot servers (robots as resources, docs/ROBOTS.md).

    python experiments/sac_franka_pick.py --robots=sim:franka_emika_panda,sim:universal_robots_ur5e \\
        --speed=20 --total_steps=3000 --logdir=runs/sac_pick

Flags beside the shared ones (``--robots``, ``--speed``, ``--dense_reward``; robot assignment and evaluation):
``unilab_jax.apps.robot_cli``. A robot lost mid-run stops its worker until the robot (or another free one) answers
again; the other workers go on, and the interrupted step writes no transition. The policy sees the robot's
proprioception, its kind and its place in the inventory; the critic also the privileged object state.
Learning shows while it trains: ``episode/success_rate`` is the success rate of the workers' recent
(stochastic) episodes.
"""

from unilab_jax import recipes
from unilab_jax.apps.robot_cli import run_robot_experiment

RECIPE = recipes.SAC_FRANKA_PICK

if __name__ == "__main__":
    run_robot_experiment(**recipes.get("sac_franka_pick").kwargs)
