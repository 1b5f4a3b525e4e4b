"""Robot tasks: MuJoCo models built through mujoco_menagerie + MjSpec, task math on the shim.

``tasks.make(name, num_envs, seed, overrides)`` builds a registered task; a built-in task's module is
imported when the task is first asked for (``tasks/base.py``). Outside packages register their own
with ``tasks.register``.
"""

from tasks.base import StepOut, Task, TaskSpec, default_config, make, names, register

__all__ = ["StepOut", "Task", "TaskSpec", "default_config", "make", "names", "register"]
