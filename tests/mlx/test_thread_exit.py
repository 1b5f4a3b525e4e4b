"""A process whose learner thread ran MLX work must exit cleanly.

MLX keeps streams per thread. Freed by the thread's C++ exit destructors while the main thread finalizes
the interpreter, they abort the process ("terminate called without an active exception", exit -6) after
the run's work is done: the notebook CI failure of 2026-11-25. Before the fix this script aborted in 20
of 20 runs on the dev VM, so a few runs show a regression.
"""

from __future__ import annotations

import threading

import pytest

mx = pytest.importorskip("mlx.core")

from mlx_helpers import run_python  # noqa: E402

from unilab_jax import xp  # noqa: E402
from unilab_jax.training.threads import LearnerThread  # noqa: E402

# The main thread and the learner thread both compute; the script ends right after close().
SCRIPT = """
import threading
import mlx.core as mx
from unilab_jax.training.threads import LearnerThread

mx.eval(mx.ones((8, 8)) * 2)
learner = LearnerThread("mlx")
stop = threading.Event()
for _ in range(5):
    learner.call(stop, lambda: mx.eval(mx.random.normal((64, 64)) @ mx.random.normal((64, 64))))
learner.close()
print("done")
"""


def test_process_exits_cleanly_after_mlx_learner_thread():
    for attempt in range(6):
        res = run_python(SCRIPT, timeout=120)
        assert res.returncode == 0 and "done" in res.stdout, (
            f"attempt {attempt}: exit {res.returncode}\n{res.stdout}\n{res.stderr}")


def test_close_waits_for_the_thread_unless_a_call_is_running():
    learner = LearnerThread("mlx")
    stop = threading.Event()
    assert learner.call(stop, lambda: (mx.ones((4,)) * 3).sum().item()) == 12.0
    learner.close()
    assert not learner._thread.is_alive()

    release = threading.Event()
    busy = LearnerThread("mlx")
    busy.submit(release.wait)
    busy.close()  # a stopped run's abandoned update: close does not wait for it
    assert busy._thread.is_alive() and busy.busy
    release.set()
    busy._thread.join(timeout=30)
    assert not busy._thread.is_alive() and not busy.busy


def test_end_thread_leaves_other_threads_streams_alone():
    """``end_thread`` frees the calling thread's streams only: the main thread computes on afterwards."""
    xp.get("mlx")
    worker = threading.Thread(target=lambda: (mx.eval(mx.ones((4, 4)) @ mx.ones((4, 4))), xp.end_thread()))
    worker.start()
    worker.join()
    assert (mx.ones((2, 2)) * 2).sum().item() == 8.0


def test_the_main_thread_frees_its_streams_at_exit():
    """Importing the shim's MLX backend registers an exit hook that runs ``mx.clear_streams()`` in the main
    thread before the interpreter finalizes (MLX asks it of every thread, the main one included)."""
    script = """
import mlx.core as mx
original = mx.clear_streams
mx.clear_streams = lambda: (print("cleared", flush=True), original())
from unilab_jax import xp
xp.get("mlx")
mx.eval(mx.ones((8, 8)) * 2)
print("done", flush=True)
"""
    res = run_python(script, timeout=120)
    assert res.returncode == 0 and res.stdout.split() == ["done", "cleared"], (res.stdout, res.stderr)
