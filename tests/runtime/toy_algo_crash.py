"""toy_algo whose policy raises on its 3rd call (to test worker-failure reporting)."""

from toy_algo import act as _act
from toy_algo import extras, init_weights  # noqa: F401

SYNC = "lockstep"
BUFFER = "trajectory"
_calls = [0]


def act(params, obs, noise, deterministic=False):
    _calls[0] += 1
    if _calls[0] >= 3:
        raise FloatingPointError("toy policy exploded on purpose")
    return _act(params, obs, noise, deterministic)
