"""The trainer's update pipeline (training/threads.py): calls queued one ahead on the learner thread, their
results read in order, non-finite results never publish weights, and a cancel drops the calls not started."""

import math
import threading

from unilab_jax.training.threads import LearnerThread, UpdatePipeline


def _counting_update(started: threading.Event, release: threading.Event):
    def update(state, batch):
        started.set()
        release.wait(5)
        return state + batch, {"loss": float(batch) if batch >= 0 else math.nan}, {"w": state + batch}
    return update


def test_calls_run_in_order_on_the_newest_state_one_call_ahead():
    thread = LearnerThread("jax")
    started, release = threading.Event(), threading.Event()
    pipe = UpdatePipeline(thread, _counting_update(started, release), 0, depth=2)
    pipe.submit(1)
    assert not pipe.full
    pipe.submit(10)
    assert pipe.full and pipe.pending == 2
    assert started.wait(5)  # the first call runs while the second is queued behind it
    release.set()
    stop = threading.Event()
    first, second = pipe.result(stop), pipe.result(stop)
    assert first[0] == {"loss": 1.0} and first[2] == {"w": 1}
    assert second[0] == {"loss": 10.0} and second[2] == {"w": 11}  # the second call updated the first's state
    assert first[1] >= 0 and pipe.pending == 0 and pipe.state == 11
    thread.close()


def test_a_non_finite_result_brings_no_weights():
    thread = LearnerThread("jax")
    started, release = threading.Event(), threading.Event()
    release.set()
    pipe = UpdatePipeline(thread, _counting_update(started, release), 5, depth=1)
    pipe.submit(-1)
    scalars, _, host = pipe.result(threading.Event())
    assert math.isnan(scalars["loss"]) and host is None
    thread.close()


def test_cancel_drops_the_queued_calls_and_keeps_the_last_finished_state():
    thread = LearnerThread("jax")
    started, release = threading.Event(), threading.Event()
    pipe = UpdatePipeline(thread, _counting_update(started, release), 0, depth=2)
    pipe.submit(1)
    pipe.submit(10)
    assert started.wait(5)
    state = pipe.cancel()  # the first call is running, the second not started
    assert state == 0 and pipe.pending == 0
    release.set()
    thread.close()
    assert pipe.state == 0  # neither the running call's result nor the dropped call reached the state
