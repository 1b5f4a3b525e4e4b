"""Session-wide checks shared by every test directory."""

from __future__ import annotations

import atexit
import os
import pathlib
import shutil
import tempfile

import pytest

# Robots load offline from ../shared/robots when that folder exists (the Makefile and CI set it too).
_ROBOTS = pathlib.Path(__file__).resolve().parents[2] / "shared" / "robots"
if _ROBOTS.is_dir():
    os.environ.setdefault("MENAGERIE_ROOT", str(_ROBOTS))

# Many tests (and the experiment scripts they start as subprocesses) compile the same learner updates:
# they share compiled XLA programs through JAX's persistent cache, in a directory made for this session
# (inherited by pytest-xdist workers and subprocesses) and removed at its end. Set before jax is imported.
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _JAX_CACHE = tempfile.mkdtemp(prefix="unilab_test_xla_")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _JAX_CACHE
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
    atexit.register(shutil.rmtree, _JAX_CACHE, True)

# `make test` hands whole files to its workers (pytest-xdist's loadfile) in collection order (pyproject's
# --no-loadscope-reorder: xdist's default order, most tests first, left the files of one or two long tests, learning
# runs and MJX compiles, for the end, one of them running alone for ~60 s). The files that took 15 s or more are
# collected first, longest first (the mean of two whole `make test` runs' walls, docs/dev/TESTING.md "Eleventh
# phase-3 session"), so short files are left for the end. test_replay_rings.py added (2026-11-28, one whole run at
# 959b6bb: 29.5 s, the late worker's last long file; the workers then ended 11.0 s apart, 991.8 and 980.8 s).
FIRST = ("test_rlpd_experiments.py", "test_offpolicy_training.py", "test_mjx_walking_parity.py", "test_mjx_training.py",
         "test_robot_runtime.py", "test_compute_dtype.py", "test_experiments.py", "test_hora_him.py",
         "test_notebooks.py", "test_flow_experiments.py", "test_ray_rollouts.py", "test_mjx_allegro_parity.py",
         "test_play_export.py", "test_pixel_learning.py", "test_web.py", "test_hgdagger.py", "test_mjx_rough.py",
         "test_replay_rings.py", "test_image_learners.py", "test_sharding.py", "test_mjx_parity.py",
         "test_mlx_only_install.py", "test_image_obs.py", "test_stop.py", "test_ppo_parity.py",
         "test_sacflow_training.py", "test_core_jit.py", "test_training.py", "test_hora_him_experiments.py",
         "test_robot_experts.py", "test_recovery.py",
         "test_offpolicy_parity.py", "test_offpolicy_learners.py", "test_api.py", "test_robot_server.py",
         "test_allegro_experiments.py")


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(FIRST)))


_SHM = "/dev/shm"
_PREFIX = "unilab_"


def _segments() -> set[str]:
    return {n for n in os.listdir(_SHM) if n.startswith(_PREFIX)} if os.path.isdir(_SHM) else set()


def _ours_or_orphaned(name: str) -> bool:
    """Created by this process, or by a process that is gone (a leak); not another live run's."""
    head = name[len(_PREFIX) :].split("_", 1)[0]
    if not head.isdigit():
        return True
    pid = int(head)
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


@pytest.fixture(scope="session", autouse=True)
def no_leaked_shared_memory():
    """Fails the session if the tests leave new ``unilab_*`` segments in /dev/shm."""
    before = _segments()
    yield
    leaked = sorted(n for n in _segments() - before if _ours_or_orphaned(n))
    if leaked:
        pytest.fail(f"shared-memory segments leaked by the test session: {leaked}", pytrace=False)
