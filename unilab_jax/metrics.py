"""TensorBoard scalars (tensorboardX), a JSON-lines copy of every logged row, a rich progress bar, and the
walking criterion every locomotion evaluation is judged by."""

from __future__ import annotations

import atexit
import dataclasses
import json
import math
import os
import queue
import sys
import threading
import time


@dataclasses.dataclass(frozen=True)
class WalkingCriterion:
    """When a locomotion policy walks: judged on ``tasks.walking_metric.walking_metric``'s numbers (deterministic
    policy, random commands), independent of any task's reward scaling.

    A policy that stands still has tracking error = the mean commanded speed (~0.5 m/s on Go1/Go2/G1) and
    yaw-rate error = the mean commanded yaw rate (~0.4-0.5 rad/s), so it fails both bounds.
    """

    max_tracking_error: float = 0.25  # mean |v_xy_cmd - v_xy| (m/s, body frame)
    max_yaw_rate_error: float = 0.3  # mean |wz_cmd - wz| (rad/s)
    max_fall_rate: float = 0.02  # fraction of the evaluated episodes that terminated

    KEYS = ("tracking_error", "yaw_rate_error", "fall_rate")

    def met(self, metric: dict[str, float], prefix: str = "") -> bool:
        """Whether ``metric`` (keys ``{prefix}tracking_error``, ``{prefix}yaw_rate_error``, ``{prefix}fall_rate``)
        meets every bound; a missing or non-finite number does not."""
        values = [metric.get(prefix + k) for k in self.KEYS]
        if any(v is None or not math.isfinite(float(v)) for v in values):
            return False
        tracking, yaw, falls = (float(v) for v in values)
        return tracking <= self.max_tracking_error and yaw <= self.max_yaw_rate_error and falls <= self.max_fall_rate

    def met_on_rough(self, metric: dict[str, float], prefix: str = "") -> bool:
        """The rough-terrain walking criterion: ``met`` by an evaluation that ran on terrain levels >= half the
        maximum level only (``{prefix}terrain_level_min >= {prefix}terrain_level_top / 2``: the lowest evaluated
        level and the grid's top level, as ``tasks/rough.py``'s ``TerrainEval`` reports them)."""
        low, top = metric.get(prefix + "terrain_level_min"), metric.get(prefix + "terrain_level_top")
        if low is None or top is None or not (math.isfinite(float(low)) and math.isfinite(float(top))):
            return False
        return float(low) >= float(top) / 2 and self.met(metric, prefix)


WALKING = WalkingCriterion()


class MetricLogger:
    """Writes scalars to TensorBoard event files and ``metrics.jsonl`` under ``logdir``, and to Weights & Biases
    when ``wandb_project`` is given (``--wandb_project``; ``pip install 'unilab-jax[wandb]'``; ``WANDB_MODE=offline``
    keeps the run under ``<logdir>/wandb`` for ``wandb sync``). W&B's x-axis is ``env_steps``: evaluations finish
    after later training rows, which W&B's own step counter would drop.

    ``log`` only queues the row: a writer thread serialises the rows, in order, and flushes ``metrics.jsonl``
    after each batch of them (the training loop logs a row per learner call; written there, ~40 TensorBoard
    scalars a row took ~18 ms of the loop per call in-run on the H100 machine, the GPU idle meanwhile). A row is
    one TensorBoard event holding all its scalars: ``add_scalar`` per scalar put an event each through
    tensorboardX's multiprocessing queue, its feeder thread and its writer thread, ~3.8 ms of the process's CPU
    for a 56-scalar training row on the dev VM (~0.2 s of GIL-held CPU per second at 54 calls/s), 0.23 ms as
    one event.
    ``flush()`` waits until every row logged so far is written; ``close()`` (or the interpreter's exit) writes the
    rest."""

    def __init__(self, logdir: str, wandb_project: str = "", wandb_config: dict | None = None):
        from tensorboardX import SummaryWriter
        from tensorboardX.proto.summary_pb2 import Summary

        self._summary = Summary
        os.makedirs(logdir, exist_ok=True)
        self.logdir = logdir
        self._tb = SummaryWriter(logdir=logdir, flush_secs=10)
        self._jsonl = open(os.path.join(logdir, "metrics.jsonl"), "a")  # noqa: SIM115 (closed in close())
        self._lock = threading.Lock()  # the learner and the evaluation thread both log
        self._wandb = None
        if wandb_project:
            import wandb

            self._wandb = wandb.init(project=wandb_project, name=os.path.basename(os.path.abspath(logdir)),
                                     dir=logdir, config=wandb_config or {})
            self._wandb.define_metric("env_steps")
            self._wandb.define_metric("*", step_metric="env_steps")
        self._tags: dict[str, str] = {}
        self._rows: queue.SimpleQueue = queue.SimpleQueue()
        self._writer = threading.Thread(target=self._write_rows, name="metrics", daemon=True)
        self._writer.start()
        self._closed = False
        atexit.register(self.close)

    def log(self, step: int, scalars: dict[str, float]) -> None:
        clean = {k: float(v) for k, v in scalars.items() if v is not None and math.isfinite(float(v))}
        self._rows.put((int(step), clean))

    def flush(self) -> None:
        """Returns once every row logged before the call is written and flushed."""
        done = threading.Event()
        self._rows.put(done)
        done.wait()

    def _write_rows(self) -> None:
        while True:
            batch = [self._rows.get()]
            while not self._rows.empty() and len(batch) < 256:
                batch.append(self._rows.get())
            with self._lock:
                for item in batch:
                    if isinstance(item, tuple):
                        try:
                            self._write(*item)
                        except Exception as e:  # a sink's failure must not stop the run's other rows
                            print(f"metrics: row of step {item[0]} not fully written: {e!r}", file=sys.stderr)
                self._jsonl.flush()
            for item in batch:
                if isinstance(item, threading.Event):
                    item.set()
                elif item is None:
                    return

    def _write(self, step: int, clean: dict[str, float]) -> None:
        if clean:  # one event holding the row's scalars (add_scalar per scalar: see the class's docstring)
            values = [self._summary.Value(tag=self._tag(k), simple_value=v) for k, v in clean.items()]
            self._tb.file_writer.add_summary(self._summary(value=values), global_step=step)
        self._jsonl.write(json.dumps({"step": step, **clean}) + "\n")
        if self._wandb is not None:
            self._wandb.log({**clean, "env_steps": step})

    def _tag(self, key: str) -> str:
        """``key``'s TensorBoard tag, as ``add_scalar`` names it (tensorboardX's cleaning, done once per key)."""
        tag = self._tags.get(key)
        if tag is None:
            from tensorboardX.summary import scalar

            tag = self._tags[key] = scalar(key, 0.0).value[0].tag
        return tag

    def image(self, step: int, tag: str, image) -> None:
        """An [H, W, 3] uint8 image in TensorBoard's images tab."""
        with self._lock:
            self._tb.add_image(tag, image, global_step=step, dataformats="HWC")

    def close(self) -> None:
        """Writes the queued rows and closes the files (once; later calls do nothing)."""
        if self._closed:
            return
        self._closed = True
        atexit.unregister(self.close)
        self._rows.put(None)
        self._writer.join()
        self._tb.flush()
        self._tb.close()
        self._jsonl.close()
        if self._wandb is not None:
            self._wandb.finish()


def evaluation_line(step: int, result: dict[str, float]) -> str:
    """The line printed when an evaluation finishes: its return and the task's own evaluation numbers."""
    shown = {k.removeprefix("eval/"): v for k, v in result.items()
             if k.startswith("eval/") and not k.endswith(("wall_s", "skipped"))}
    first = ["return"] if "return" in shown else []
    parts = [f"{k} {shown[k]:.4g}" for k in first + sorted(k for k in shown if k != "return")]
    return f"eval at step {int(step):,}: " + ("  ".join(parts) or "(no result)")


class ProgressBar:
    """A rich progress bar with env steps/s and ETA; when stdout is not a terminal (a log file, a cluster job),
    a plain line at the first update and then every ``PLAIN_EVERY_S`` seconds, from a timer thread, so lines keep
    coming while the learner compiles or waits (the step count then stands still)."""

    PLAIN_EVERY_S = 10.0

    def __init__(self, total: int, start: int = 0):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self._plain = not sys.stdout.isatty()
        self._progress = Progress(TextColumn("[bold]training"), BarColumn(), MofNCompleteColumn(),
                                  TextColumn("{task.fields[rate]} steps/s"), TextColumn("return {task.fields[ret]}"),
                                  TimeRemainingColumn(), disable=self._plain)
        self._task = self._progress.add_task("train", total=total, completed=start, rate="-", ret="-")
        self._progress.start()
        self._start_step = self._step = start
        self._total = total
        self._ret = "-"
        self._t0 = time.time()
        self._lock = threading.Lock()
        self._printed = False
        self._closed = threading.Event()
        self._timer = None
        if self._plain:
            self._timer = threading.Thread(target=self._tick, name="progress", daemon=True)
            self._timer.start()

    def _line(self) -> str:
        rate = (self._step - self._start_step) / max(time.time() - self._t0, 1e-9)
        return f"step {self._step:,}/{self._total:,}  {rate:,.0f} env steps/s  episode return {self._ret}"

    def _tick(self) -> None:
        while not self._closed.wait(self.PLAIN_EVERY_S):
            with self._lock:
                print(self._line(), flush=True)

    def update(self, step: int, episode_return: float | None) -> None:
        with self._lock:
            self._step = step
            if episode_return is not None:
                self._ret = f"{episode_return:.3f}"
            rate = (step - self._start_step) / max(time.time() - self._t0, 1e-9)
            self._progress.update(self._task, completed=step, rate=f"{rate:,.0f}", ret=self._ret)
            if self._plain and not self._printed:  # the first line at once, then the timer's
                self._printed = True
                print(self._line(), flush=True)

    def close(self) -> None:
        self._closed.set()
        if self._timer is not None:
            self._timer.join()
        self._progress.stop()
