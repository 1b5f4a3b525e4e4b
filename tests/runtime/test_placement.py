"""Worker CPU placement: ``cpu_placement`` shares, and a real pool's workers pinned to them."""

from __future__ import annotations

import os

import numpy as np
import pytest
import toy_algo  # noqa: F401  (the workers import it by name)

from unilab_jax.runtime import WorkerPool
from unilab_jax.runtime.spawn import cpu_placement

pytestmark = pytest.mark.timeout(120)


def test_cpu_placement_leaves_the_learner_cores_free():
    assert cpu_placement(15, 1, range(16)) == [[c] for c in range(1, 16)]
    assert cpu_placement(4, 2, range(10)) == [[2, 3], [4, 5], [6, 7], [8, 9]]
    assert cpu_placement(3, 0, [5, 1, 3]) == [[1], [3], [5]]  # sorted CPU ids, whatever the given order
    assert cpu_placement(5, 1, range(3)) == [[1], [2], [1], [2], [1]]  # more workers than CPUs: shared
    for bad in (-1, 3):
        with pytest.raises(ValueError, match="learner_cores"):
            cpu_placement(2, bad, range(3))


def test_pool_pins_each_worker():
    usable = sorted(os.sched_getaffinity(0))
    cpus = [[usable[-1]], usable[-2:]] if len(usable) > 1 else [usable, usable]
    weights = {"w": np.zeros((1, 5), np.float32), "log_std": np.full((1,), -1.0, np.float32)}
    pool = WorkerPool("cartpole_balance", {}, num_workers=2, envs_per_worker=2, seed=0, algo_module="toy_algo",
                      weight_template=weights, horizon=4, worker_cpus=cpus)
    try:
        pool.start(timeout=60)
        assert [sorted(os.sched_getaffinity(p.pid)) for p in pool._procs] == [sorted(c) for c in cpus]
    finally:
        pool.close()
    with pytest.raises(ValueError, match="worker_cpus"):
        WorkerPool("cartpole_balance", {}, num_workers=2, envs_per_worker=2, seed=0, algo_module="toy_algo",
                   weight_template=weights, worker_cpus=[[0]])
