"""toy_algo (lock-step trajectories) with the NaN toy tasks registered in the workers."""

import toy_nan_task  # noqa: F401  (registers toy_nan / toy_nan_noreset where the workers build tasks)
from toy_algo import act, extras, init_weights  # noqa: F401

SYNC = "lockstep"
BUFFER = "trajectory"
