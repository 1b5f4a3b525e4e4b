"""HORA on Allegro in-hand rotation, its own task: a teacher that reads the object's parameters (mass,
centre of mass, friction, size, shape) and state (position, orientation, velocities), then a student that
infers them from 30 frames of proprioceptive history; one command (see unilab_jax/apps/hora_cli.py). The two
are compared on rotation rate.

    python experiments/hora_allegro.py --num_workers=15 --envs_per_worker=64 --teacher_steps=60000000 \\
        --student_steps=10000000 --logdir=runs/hora_allegro
    python experiments/hora_allegro.py --logdir=runs/hora_allegro --resume   # continues the stage that was cut off
"""

from unilab_jax import recipes
from unilab_jax.apps.hora_cli import run_hora

TASK_RECIPE = recipes.HORA_ALLEGRO_TASK
TEACHER_RECIPE = recipes.PPO_ALLEGRO_ROTATE
STUDENT_RECIPE = recipes.HORA_ALLEGRO_STUDENT

if __name__ == "__main__":
    run_hora(**recipes.get("hora_allegro").kwargs)
