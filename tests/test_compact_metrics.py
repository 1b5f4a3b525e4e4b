"""bench/compact_metrics.py: one training row per window, evaluations kept, per-episode metrics as window means."""

import gzip
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "bench"))

from compact_metrics import bin_by_wall, compact  # noqa: E402


def test_windows_keep_evaluations_and_average_the_episode_metrics_they_saw(tmp_path):
    rows = [{"step": 0, "perf/env_steps_per_s": 1.0},
            {"step": 200, "episode/late_fraction": 0.5, "loss/critic": 3.0},
            {"step": 400, "episode/late_fraction": 0.25, "other": 1},
            {"step": 400, "eval/success_rate": 0.9},
            {"step": 500, "perf/env_steps_per_s": 2.0},  # ended no episode: reports the mean of the two above
            {"step": 700, "episode/late_fraction": 1.0},
            {"step": 1100, "episode/intervention_rate": 0.2}]
    src, dst = tmp_path / "metrics.jsonl", tmp_path / "out.jsonl.gz"
    src.write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert compact(str(src), str(dst)) == 4
    out = [json.loads(line) for line in gzip.open(dst, "rt")]
    assert out[0] == {"step": 0, "perf/env_steps_per_s": 1.0}
    assert out[1] == {"step": 400, "eval/success_rate": 0.9}
    assert out[2] == {"step": 500, "perf/env_steps_per_s": 2.0, "episode/late_fraction": 0.375}
    assert out[3] == {"step": 1100, "episode/late_fraction": 1.0, "episode/intervention_rate": 0.2}


def test_wall_bins_average_every_scalar_and_keep_evaluations(tmp_path):
    rows = [{"step": 10, "time/wall_s": 0.1, "a": 1.0},
            {"step": 20, "time/wall_s": 0.4, "a": 3.0, "b": 2.0},
            {"step": 20, "eval/return": 5.0},  # closes the bin: rows after it start a new one
            {"step": 30, "time/wall_s": 0.45, "a": 5.0},
            {"step": 40, "time/wall_s": 0.6, "a": 7.0},
            {"step": 50, "time/wall_s": 0.9, "a": 9.0}]
    src, dst = tmp_path / "metrics.jsonl", tmp_path / "out.jsonl.gz"
    src.write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert bin_by_wall(str(src), str(dst), 0.5) == 4
    out = [json.loads(line) for line in gzip.open(dst, "rt")]
    assert out[0] == {"step": 20, "time/wall_s": 0.4, "a": 2.0, "b": 2.0, "compact/rows": 2}
    assert out[1] == {"step": 20, "eval/return": 5.0}
    assert out[2] == {"step": 30, "time/wall_s": 0.45, "a": 5.0, "compact/rows": 1}
    assert out[3] == {"step": 50, "time/wall_s": 0.9, "a": 8.0, "compact/rows": 2}
