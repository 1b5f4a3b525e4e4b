"""The trainer's update pipeline (training/threads.py): calls queued one ahead on the learner thread, their
results fetched in order by the reading thread, non-finite results never publish weights, and a cancel drops the
calls not started."""

import math
import threading

import numpy as np

from unilab_jax.training.threads import LearnerThread, UpdatePipeline


def _counting_update(started: threading.Event, release: threading.Event):
    def update(state, batch):
        started.set()
        release.wait(5)
        return state + batch, (batch, state + batch)
    return update


def _fetch(out):
    batch, new_state = out
    return {"loss": float(batch) if batch >= 0 else math.nan}, {"w": new_state, "by": threading.current_thread().name}


def test_calls_run_in_order_on_the_newest_state_one_call_ahead():
    thread = LearnerThread("jax")
    started, release = threading.Event(), threading.Event()
    pipe = UpdatePipeline(thread, _counting_update(started, release), _fetch, 0, depth=2)
    pipe.submit(1)
    assert not pipe.full
    pipe.submit(10)
    assert pipe.full and pipe.pending == 2
    assert started.wait(5)  # the first call runs while the second is queued behind it
    release.set()
    stop = threading.Event()
    first, second = pipe.result(stop), pipe.result(stop)
    assert first[0]["loss"] == 1.0 and first[3]["w"] == 1
    assert second[0]["loss"] == 10.0 and second[3]["w"] == 11  # the second call updated the first's state
    assert first[1] >= 0 and first[2] >= 0 and pipe.pending == 0 and pipe.state == 11
    # the results are fetched by the thread that reads them, not the learner thread
    assert first[3]["by"] == threading.current_thread().name
    thread.close()


def test_fetch_on_thread_fetches_on_the_learner_thread():
    thread = LearnerThread("jax", name="the-learner")
    started, release = threading.Event(), threading.Event()
    release.set()
    pipe = UpdatePipeline(thread, _counting_update(started, release), _fetch, 0, depth=1, fetch_on_thread=True)
    pipe.submit(2)
    scalars, _, _, host = pipe.result(threading.Event())
    assert host == {"w": 2, "by": "the-learner"} and scalars == {"loss": 2.0}
    thread.close()


def test_a_non_finite_result_brings_no_weights():
    thread = LearnerThread("jax")
    started, release = threading.Event(), threading.Event()
    release.set()
    pipe = UpdatePipeline(thread, _counting_update(started, release), _fetch, 5, depth=1)
    pipe.submit(-1)
    scalars, _, _, host = pipe.result(threading.Event())
    assert math.isnan(scalars["loss"]) and host is None
    thread.close()


def test_cancel_drops_the_queued_calls_and_keeps_the_last_finished_state():
    thread = LearnerThread("jax")
    started, release = threading.Event(), threading.Event()
    pipe = UpdatePipeline(thread, _counting_update(started, release), _fetch, 0, depth=2)
    pipe.submit(1)
    pipe.submit(10)
    assert started.wait(5)
    state = pipe.cancel()  # the first call is running, the second not started
    assert state == 0 and pipe.pending == 0
    release.set()
    thread.close()
    assert pipe.state == 0  # neither the running call's result nor the dropped call reached the state


def test_weights_fetched_after_the_next_update_donated_their_state():
    """The trainer's halves on a donating update (as on accelerators): call k's weights are copied on the device
    at dispatch, so call k+1, queued before they are fetched, may take (donate) call k's state."""
    import jax

    from unilab_jax.training.trainer import _device_copy

    step = jax.jit(lambda s, b: ({"w": s["w"] + b}, {"b": b}), donate_argnums=0)

    def update(state, batch):
        state, metrics = step(state, batch)
        return state, _device_copy((metrics, state))

    def fetch(out):
        metrics, weights = jax.device_get(out)
        return {"loss": float(metrics["b"])}, weights

    thread = LearnerThread("jax")
    pipe = UpdatePipeline(thread, update, fetch, {"w": jax.numpy.zeros(3)}, depth=2)
    stop, seen = threading.Event(), []
    for b in (1.0, 2.0, 3.0):
        pipe.submit(b)
        if pipe.full:
            seen.append(pipe.result(stop))
    seen.append(pipe.result(stop))
    assert [s[0]["loss"] for s in seen] == [1.0, 2.0, 3.0]
    assert [s[3]["w"].tolist() for s in seen] == [[1.0] * 3, [3.0] * 3, [6.0] * 3]
    assert np.asarray(pipe.state["w"]).tolist() == [6.0] * 3
    thread.close()
