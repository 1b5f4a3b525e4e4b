"""``MetricLogger``: rows queued by ``log`` reach ``metrics.jsonl`` and TensorBoard in order, from any thread."""

from __future__ import annotations

import glob
import json
import os
import struct
import threading

from unilab_jax.metrics import MetricLogger


def _rows(logdir: str) -> list[dict]:
    return [json.loads(line) for line in open(os.path.join(logdir, "metrics.jsonl"))]


def test_rows_are_written_in_order_flushed_on_demand_and_at_close(tmp_path):
    logger = MetricLogger(str(tmp_path))
    for step in range(500):
        logger.log(step, {"loss": step * 0.5, "bad": float("nan")})
    logger.flush()
    rows = _rows(str(tmp_path))
    assert [r["step"] for r in rows] == list(range(500)) and rows[3] == {"step": 3, "loss": 1.5}
    # Two threads log at once (the loop and the evaluation thread): every row is written exactly once.
    threads = [threading.Thread(target=lambda base=base: [logger.log(base + i, {"x": 1.0}) for i in range(300)])
               for base in (1000, 2000)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    logger.log(5000, {"last": 2.0})
    logger.close()
    logger.close()  # a second close does nothing
    steps = [r["step"] for r in _rows(str(tmp_path))]
    assert sorted(steps[500:-1]) == list(range(1000, 1300)) + list(range(2000, 2300)) and steps[-1] == 5000
    assert glob.glob(str(tmp_path / "events.out.tfevents.*"))


def _events(logdir: str) -> list:
    """The Event protos of the run's TensorBoard file (TFRecord: length, its CRC, the record, its CRC)."""
    from tensorboardX.proto.event_pb2 import Event

    (path,) = glob.glob(os.path.join(logdir, "events.out.tfevents.*"))
    data, events, i = open(path, "rb").read(), [], 0
    while i < len(data):
        (n,) = struct.unpack("<Q", data[i:i + 8])
        events.append(Event.FromString(data[i + 12:i + 12 + n]))
        i += 12 + n + 4
    return events


def test_a_row_is_one_tensorboard_event_with_add_scalars_tags(tmp_path):
    logger = MetricLogger(str(tmp_path))
    logger.log(7, {"loss/critic": 1.5, "perf/update s": 0.25, "skipped": float("inf")})
    logger.log(8, {"loss/critic": 0.5})
    logger.log(9, {})
    logger.close()
    events = [e for e in _events(str(tmp_path)) if e.HasField("summary")]  # the first holds the file version
    rows = [(e.step, {v.tag: v.simple_value for v in e.summary.value}) for e in events]
    # tags as add_scalar names them ("perf/update s" -> "perf/update_s"); no event for a row without scalars
    assert rows == [(7, {"loss/critic": 1.5, "perf/update_s": 0.25}), (8, {"loss/critic": 0.5})]
