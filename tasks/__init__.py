"""Robot tasks: MuJoCo models built through mujoco_menagerie + MjSpec, task math on the shim.

Importing ``tasks`` registers the built-in tasks; ``tasks.make(name, num_envs, seed, overrides)``
builds one. Outside packages register their own with ``tasks.register``.
"""

from tasks.base import StepOut, Task, TaskSpec, default_config, make, names, register

__all__ = ["StepOut", "Task", "TaskSpec", "default_config", "make", "names", "register"]
