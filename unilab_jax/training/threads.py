"""The trainer's threads: the learner thread (every learner call, so a stop never waits long for a compile
or an update) and the pipeline that queues the updates on it, the prefetch thread (the next batch collected,
sampled and moved to the device while the update runs), and the SIGINT / SIGTERM handling that stops a run."""

from __future__ import annotations

import logging
import math
import queue
import signal
import threading
import time
import weakref
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any

from unilab_jax.runtime.ring import StopRequested
from unilab_jax.xp import end_thread

log = logging.getLogger(__name__)


def stop_on_signals(stop: threading.Event) -> Callable[[], None]:
    """SIGINT and SIGTERM set ``stop`` (the loop and every wait of the main thread check it); a second
    SIGINT raises ``KeyboardInterrupt`` at once. Returns the function that puts the old handlers back.
    Only the main thread can own signal handlers: elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def handler(signum: int, frame: Any) -> None:
        _SIGNALLED.set()
        if signum == signal.SIGINT and stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    old = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    return lambda: [signal.signal(sig, h) for sig, h in old.items()]


_LEARNER_THREADS: weakref.WeakSet = weakref.WeakSet()
_SIGNALLED = threading.Event()  # a run's SIGINT/SIGTERM handler ran in this process


def stopped_by_signal() -> bool:
    """Whether a run in this process was stopped by SIGINT or SIGTERM."""
    return _SIGNALLED.is_set()


def learner_busy() -> bool:
    """Whether a stopped run left a learner call running (a compile or an update it did not wait for)."""
    return any(t.busy for t in _LEARNER_THREADS)


class LearnerThread:
    """Runs the learner's calls in one dedicated daemon thread, in order, so that the main thread stays
    free to notice a stop during a long first compile or a slow update.

    ``call(stop, fn, *args)`` returns ``fn(*args)`` or raises :class:`StopRequested` once ``stop`` is set,
    without waiting for ``fn``: the call goes on in the background (``busy``) and its result is dropped.
    The caller keeps its last completed state (valid unless the call donated it: see ``Trainer``).
    ``submit`` queues a call and returns its ``Future`` at once. MLX keeps a default stream per thread,
    so the thread makes its own.
    """

    _POLL_S = 0.05

    def __init__(self, platform: str, name: str = "learner"):
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._pending = 0
        self._thread = threading.Thread(target=self._loop, args=(platform,), name=name, daemon=True)
        self._thread.start()
        _LEARNER_THREADS.add(self)

    @property
    def busy(self) -> bool:
        with self._lock:
            return self._pending > 0

    def _loop(self, platform: str) -> None:
        if platform == "mlx":
            import mlx.core as mx

            mx.set_default_stream(mx.new_stream(mx.default_device()))
        try:
            while True:
                job = self._jobs.get()
                if job is None:
                    return
                fn, args, future = job
                error: BaseException | None = None
                try:
                    result = fn(*args)
                except BaseException as e:  # handed to whoever waits on the future
                    error = e
                with self._lock:  # not busy once the caller can see the result
                    self._pending -= 1
                if error is None:
                    future.set_result(result)
                else:
                    future.set_exception(error)
        finally:
            end_thread()

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        future: Future = Future()
        with self._lock:
            self._pending += 1
        self._jobs.put((fn, args, future))
        return future

    def call(self, stop: threading.Event, fn: Callable[..., Any], *args: Any, grace_s: float = 0.0) -> Any:
        """``fn(*args)`` in the thread; after a stop, waits ``grace_s`` more for it to finish."""
        if stop.is_set():
            raise StopRequested("stop requested before a learner call")
        return wait_result(self.submit(fn, *args), stop, grace_s)

    def close(self) -> None:
        """Ends the thread after the calls queued so far; waits for that unless a call is still running
        (a stopped run does not wait for an abandoned update)."""
        self._jobs.put(None)
        if not self.busy:
            self._thread.join(timeout=60)


def wait_result(future: Future, stop: threading.Event, grace_s: float = 0.0) -> Any:
    """``future.result()``, or :class:`StopRequested` once ``stop`` is set and ``grace_s`` more seconds have
    passed without a result (the call is then not waited for)."""
    while True:
        try:
            return future.result(timeout=LearnerThread._POLL_S)
        except FutureTimeout:
            if stop.is_set():
                break
    try:
        return future.result(timeout=grace_s)
    except FutureTimeout:
        raise StopRequested("stop requested during a learner call (left running in the background)") from None


class Prefetcher:
    """Runs ``produce()`` in a thread, one item ahead, so collection, sampling and the host-to-device
    copy overlap with the learner's update. Errors surface in the learner thread.

    ``inline`` (serial mode): ``produce`` runs in the caller's thread instead, so a serial run is one
    deterministic sequence of env steps, samples, updates and weight publications; in a thread the
    next batch's env steps would race the publication of the weights they should use.
    """

    def __init__(self, produce: Any, depth: int = 1, inline: bool = False):
        self._produce = produce
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._thread = None if inline else threading.Thread(target=self._loop, name="prefetch", daemon=True)
        if self._thread is not None:
            self._thread.start()

    def _loop(self) -> None:
        try:
            while not self._stop.is_set():
                item = self._produce(self._stop)
                if item is None:
                    continue
                while not self._stop.is_set():
                    try:
                        self._queue.put(item, timeout=0.2)
                        break
                    except queue.Full:
                        continue
        except BaseException as e:  # surfaced to the learner thread (unless we are stopping)
            if not self._stop.is_set():
                self._queue.put(e)
        finally:
            end_thread()

    def get(self, stop: threading.Event | None = None) -> tuple[dict, dict]:
        """The next item; raises :class:`StopRequested` when ``stop`` is set while waiting for it."""
        if self._thread is None:
            item = self._produce(self._stop)
            if item is None:
                raise RuntimeError("the batch source was stopped")
            return item
        while True:
            try:
                item = self._queue.get(timeout=0.1)
            except queue.Empty:
                if stop is not None and stop.is_set():
                    raise StopRequested("stop requested while waiting for a batch") from None
                if not self._thread.is_alive():
                    raise RuntimeError("prefetch thread stopped") from None
                continue
            if isinstance(item, BaseException):
                raise item
            return item

    def stop(self) -> None:
        """Asks the thread to stop; it exits once the pool closes (a pending collect then raises)."""
        self._stop.set()

    def join(self) -> None:
        if self._thread is not None:
            self._thread.join(timeout=10)


class UpdatePipeline:
    """The learner's state and its updates, queued on a :class:`LearnerThread` up to ``depth`` calls ahead.

    A call is two halves: ``update(state, batch) -> (state, out)`` runs on the learner thread and only dispatches
    the work (on JAX it returns as soon as the update is queued on the device: ``out`` holds device arrays);
    ``fetch(out) -> (scalars, host weights)`` brings the results to the host (waiting for the device) and runs in
    the thread that reads the result (``result``), or on the learner thread too with ``fetch_on_thread`` (MLX,
    whose arrays belong to the thread's stream). ``submit(batch)`` queues one update of the newest state and
    returns at once; ``result(stop, grace_s)`` waits for the oldest queued call and returns its scalars, the
    seconds its dispatch took on the learner thread, the seconds of its fetch, and its host weights when every
    scalar is finite, else None. With ``depth`` 2 the loop queues call k+1 before it reads call k's results, so
    the device never waits for host work between calls: call k+1 is queued on the device while call k's results
    are copied, converted, published and logged (the loop sees a call's results one call late and publishes the
    weights of the call it reads). Depth 1 (serial runs) is one call at a time, as a plain loop. Read ``state``
    once every queued call's result was read (before an evaluation or a checkpoint); ``cancel`` drops the queued
    calls that have not started and returns the state the loop may save (a call already running finishes in the
    background, its result dropped).
    """

    def __init__(self, thread: LearnerThread, update: Callable[[Any, Any], tuple[Any, Any]],
                 fetch: Callable[[Any], tuple[dict[str, float], Any]], state: Any, depth: int,
                 fetch_on_thread: bool = False):
        if depth < 1:
            raise ValueError(f"UpdatePipeline: depth must be >= 1, got {depth}")
        self._thread, self._update, self._fetch, self.depth = thread, update, fetch, depth
        self._fetch_on_thread = fetch_on_thread
        self._state = state
        self._lock = threading.Lock()
        self._cancelled = False
        self._queued: list[Future] = []

    @property
    def state(self) -> Any:
        """The newest state; read it once no call is queued (a queued call may otherwise replace or donate it)."""
        with self._lock:
            return self._state

    @property
    def full(self) -> bool:
        """Whether ``depth`` calls are queued, so the oldest must be read before another is submitted."""
        return len(self._queued) >= self.depth

    @property
    def pending(self) -> int:
        return len(self._queued)

    def _run(self, batch: Any) -> tuple[Any, float, float, bool]:
        with self._lock:
            if self._cancelled:
                return ({}, None), 0.0, 0.0, True
            state = self._state
        t0 = time.perf_counter()
        state, out = self._update(state, batch)
        seconds = time.perf_counter() - t0
        with self._lock:
            if not self._cancelled:
                self._state = state
        if not self._fetch_on_thread:
            return out, seconds, 0.0, False
        t1 = time.perf_counter()
        return self._fetch(out), seconds, time.perf_counter() - t1, True

    def submit(self, batch: Any) -> None:
        self._queued.append(self._thread.submit(self._run, batch))

    def result(self, stop: threading.Event, grace_s: float = 0.0) -> tuple[dict[str, float], float, float, Any]:
        """The oldest queued call's (scalars, dispatch seconds, fetch seconds, host weights or None);
        :class:`StopRequested` once ``stop`` is set (after ``grace_s`` more seconds without a dispatched call)."""
        out, seconds, fetch_s, fetched = wait_result(self._queued.pop(0), stop, grace_s)
        if not fetched:
            t0 = time.perf_counter()
            out = self._fetch(out)
            fetch_s = time.perf_counter() - t0
        scalars, host = out
        if not all(math.isfinite(v) for v in scalars.values()):
            host = None
        return scalars, seconds, fetch_s, host

    def cancel(self) -> Any:
        """Drops the calls not yet started; returns the state of the last call that finished."""
        with self._lock:
            self._cancelled = True
            self._queued.clear()
            return self._state
