"""SAC on peg insertion through robot servers, without prior data: the baseline of ``rlpd_franka_peg.py``.

    python experiments/sac_franka_peg.py --speed=20 --total_steps=2000 --logdir=runs/sac_peg

Same networks, observations (``--observation=images`` by default, or ``state``), reward (success only), batch
and update-to-data ratio as ``rlpd_franka_peg.py``; SAC's twin critics and no demonstrations. Flags and recipe:
``unilab_jax.apps.robot_cli``.
"""

from unilab_jax import recipes
from unilab_jax.apps.robot_cli import run_robot_experiment

if __name__ == "__main__":
    run_robot_experiment(**recipes.get("sac_franka_peg").kwargs)
