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

# The slowest test files (seconds on the idle 2-core VM, measured for issue 36), run first: `make test` hands
# files to its pytest-xdist workers in collection order (--dist loadfile --no-loadscope-reorder), so the long
# files start at once and the many short ones fill in behind them, and both workers finish together (xdist's
# default order, by number of tests per file, left these few-test files for the end, one worker running on alone).
SLOW_FILES_FIRST = (
    "tests/robots/test_rlpd_experiments.py",  # ~135 (two robot experiments, one of them a learning test)
    "tests/tasks/test_mjx_walking_parity.py",  # ~115 (MJX compiles of Go2 and G1)
    "tests/test_mjx_training.py",  # ~105 (MJX compiles of two training loops)
    "tests/test_offpolicy_training.py",  # ~95 (five learning runs)
    "tests/test_experiments.py",  # ~60
    "tests/algos/test_compute_dtype.py",  # ~50
    "tests/robots/test_flow_experiments.py",  # ~40
    "tests/test_hora_him.py",  # ~38
    "tests/test_hora_him_experiments.py",  # ~36
    "tests/test_play_export.py",  # ~30
    "tests/mlx/test_offpolicy_parity.py",  # ~27
    "tests/robots/test_robot_runtime.py",  # ~23
    "tests/tasks/test_mjx_allegro_parity.py",  # ~22
    "tests/test_sacflow_training.py",  # ~21
    "tests/test_mlx_only_install.py",  # ~19
    "tests/test_sharding.py",  # ~19
    "tests/mlx/test_ppo_parity.py",  # ~19
    "tests/test_ray_rollouts.py",  # ~17
)


def pytest_collection_modifyitems(session, config, items):
    """Moves the files of ``SLOW_FILES_FIRST`` to the front, in that order; a stable sort, so the tests within
    a file and the other files keep their order."""
    rank = {f: i for i, f in enumerate(SLOW_FILES_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::", 1)[0], len(rank)))


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
