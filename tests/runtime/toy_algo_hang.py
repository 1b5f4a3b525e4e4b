"""toy_algo whose policy hangs on one call, so a test can kill a worker in the middle of a slot.

The call number (0-based, per process) comes from ``TOY_HANG_AT_CALL`` in the environment the
worker was spawned with; a respawned process started after the test removed it never hangs.
"""

import os
import time

from toy_algo import act as _act
from toy_algo import extras, init_weights  # noqa: F401

SYNC = "lockstep"
BUFFER = "trajectory"
_HANG_AT = int(os.environ.get("TOY_HANG_AT_CALL", "-1"))
_calls = [0]


def act(params, obs, noise, deterministic=False):
    if _calls[0] == _HANG_AT:
        time.sleep(3600)
    _calls[0] += 1
    return _act(params, obs, noise, deterministic)
