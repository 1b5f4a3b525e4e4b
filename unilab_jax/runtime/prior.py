"""Prior data (demonstrations, earlier runs) read from a persistent replay store for off-policy learners.

``load_prior(directory, layout)`` returns every committed row of the store in ``directory``
(:mod:`unilab_jax.runtime.replay_store`'s format) as ``{field: [N, ...]}`` for the fields of
``layout``, checking that their shapes and dtypes are the run's. The store's lock is held only while
reading (several runs may load one demonstrations folder; a locked store is retried for ``wait_s``).
"""

from __future__ import annotations

import os
import time

import numpy as np

from unilab_jax.runtime.buffers import FieldLayout
from unilab_jax.runtime.replay_store import INDEX, ReplayStore, StoreLockedError


class PriorDataError(ValueError):
    """The prior-data folder is missing, empty or holds transitions of another shape."""


def load_prior(directory: str, layout: FieldLayout, wait_s: float = 30.0) -> dict[str, np.ndarray]:
    """Every committed row of the store in ``directory``, fields of ``layout`` only (see the module)."""
    if not os.path.isfile(os.path.join(directory, INDEX)):
        raise PriorDataError(f"prior data {directory!r}: no replay store there ({INDEX} missing)")
    deadline = time.monotonic() + wait_s
    while True:
        try:
            store = ReplayStore(directory, verify=True)
            break
        except StoreLockedError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)
    try:
        for name, (shape, dtype) in layout.items():
            if name not in store.fields:
                raise PriorDataError(f"prior data {directory!r} has no field {name!r} (has {sorted(store.fields)})")
            got = store.fields[name]
            if tuple(got[0]) != tuple(shape) or np.dtype(got[1]) != np.dtype(dtype):
                raise PriorDataError(f"prior data {directory!r}: field {name!r} is {tuple(got[0])} {np.dtype(got[1])}, "
                                     f"this run needs {tuple(shape)} {np.dtype(dtype)} (recorded with another task "
                                     "or robot inventory?)")
        if store.size == 0:
            raise PriorDataError(f"prior data {directory!r} holds no committed transitions")
        rows = store.read(store.first_row, store.committed)
    finally:
        store.close()
    return {name: rows[name] for name in layout}
