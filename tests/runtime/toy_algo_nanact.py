"""toy_algo whose policy returns NaN actions on a fixed schedule (as NaN weights would).

On its ``c``-th call (0-based, counted per worker process) env ``e`` gets a NaN action when
:func:`nan_envs` says so; its log-probability is NaN then too.
"""

import numpy as np
from toy_algo import act as _act
from toy_algo import extras, init_weights  # noqa: F401

SYNC = "lockstep"
BUFFER = "trajectory"
_calls = [0]


def nan_envs(call: int, m: int) -> np.ndarray:
    return (call + np.arange(m)) % 5 == 0


def act(params, obs, noise, deterministic=False):
    action, ex = _act(params, obs, noise, deterministic)
    bad = nan_envs(_calls[0], obs.shape[0])
    _calls[0] += 1
    action[bad] = np.nan
    ex["log_prob"][bad] = np.nan
    return action, ex
