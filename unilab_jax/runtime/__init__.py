"""Runtime: shared-memory buffers, weight channel, rollout workers and the worker pool.

Imports numpy, mujoco (through the tasks, in the workers) and the standard library only; never jax.
See ``docs/ARCHITECTURE.md`` ("Runtime") for the data flow and the memory-ordering argument.
"""

from unilab_jax.runtime.buffers import ReplayBuffer, TrajectoryBuffer, transition_layout
from unilab_jax.runtime.pool import WorkerDiedError, WorkerPool
from unilab_jax.runtime.ring import StopRequested
from unilab_jax.runtime.shm import SharedArrays, ShmSpaceError, cleanup_stale
from unilab_jax.runtime.weights import WeightChannel, WeightReader

__all__ = [
    "ReplayBuffer",
    "SharedArrays",
    "ShmSpaceError",
    "StopRequested",
    "TrajectoryBuffer",
    "WeightChannel",
    "WeightReader",
    "WorkerDiedError",
    "WorkerPool",
    "cleanup_stale",
    "transition_layout",
]
