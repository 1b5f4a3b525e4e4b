"""toy_algo on replay rings (async) whose policy takes 2 ms per call (a kill lands mid-step)."""

import time

from toy_algo import act as _act
from toy_algo import extras, init_weights  # noqa: F401

SYNC = "async"
BUFFER = "replay"


def act(params, obs, noise, deterministic=False):
    time.sleep(0.002)
    return _act(params, obs, noise, deterministic)
