"""HORA on Go1 joystick flat: a teacher that reads the domain-randomisation parameters, then a student
that infers them from 30 frames of proprioceptive history; one command (see unilab_jax/apps/hora_cli.py).

    python experiments/hora_go1.py --num_workers=15 --envs_per_worker=128 --teacher_steps=40000000 \\
        --student_steps=10000000 --logdir=runs/hora_go1
    python experiments/hora_go1.py --logdir=runs/hora_go1 --resume   # continues the stage that was cut off

Sized for a 16-core H100 host (15 workers x 128 envs, as above; the flag defaults are 2 x 32).
"""

from unilab_jax import recipes
from unilab_jax.apps.hora_cli import run_hora

TASK_RECIPE = recipes.HORA_GO1_TASK
TEACHER_RECIPE = recipes.PPO_GO1
STUDENT_RECIPE = recipes.HORA_GO1_STUDENT

if __name__ == "__main__":
    run_hora(**recipes.get("hora_go1").kwargs)
