"""FastSAC on Go1 joystick flat, GPU-resident: MJX envs, a replay ring in device memory, one jitted loop.

    python experiments/fastsac_go1_mjx.py --num_envs=1024 --eval_every=2000000 --logdir=runs/fastsac_go1_mjx

The recipe of ``fastsac_go1.py`` (networks, C51 support, batch 8192, 8 gradient steps per 1024
transitions); with 1024 envs each iteration is one env step of every env followed by 8 gradient steps.
"""

from unilab_jax import recipes
from unilab_jax.apps.mjx_cli import run_mjx_experiment

if __name__ == "__main__":
    run_mjx_experiment(**recipes.get("fastsac_go1_mjx").kwargs)
