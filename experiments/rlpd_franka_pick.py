"""RLPD on pick-and-place (a cube into a bin) through robot servers, with 20 demonstrations::

    python experiments/rlpd_franka_pick.py --speed=20 --total_steps=2000 --logdir=runs/rlpd_pick

Everything as in ``rlpd_franka_peg.py`` (demonstrations recorded on first use or ``--demos=DIR``, symmetric
sampling, the critic ensemble, images and proprioception in the policy's observation or ``--observation=state``,
success-only reward) on the pick-and-place task.
"""

from unilab_jax import recipes
from unilab_jax.apps.robot_cli import run_robot_experiment

if __name__ == "__main__":
    run_robot_experiment(**recipes.get("rlpd_franka_pick").kwargs)
