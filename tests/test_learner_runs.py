"""bench/learner_runs.py: time-to-walking records and metrics -> in-run learner rates per run."""

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(ROOT, "bench", "learner_runs.py")


def test_rates_over_the_window_and_from_the_start(tmp_path):
    metrics = tmp_path / "metrics"
    metrics.mkdir()
    # calls every 0.05 s from 30 s to 120 s (20 calls/s), dispatch 30 ms then 20 ms after 100 s; one eval row
    rows = [{"step": i, "time/wall_s": 30 + 0.05 * i, "perf/update_s": 0.03 if 30 + 0.05 * i < 100 else 0.02,
             "perf/fetch_s": 0.01, "perf/utd": 0.002} for i in range(1801)]
    rows.insert(5, {"step": 5, "eval/return": 1.0, "time/wall_s": 30.3})
    (metrics / "fastsac_async_s3_x.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    ttt = tmp_path / "ttt.json"
    ttt.write_text(json.dumps({"records": [{"config": "fastsac_async", "seed": 3, "max_seconds": 120.0,
                                            "logdir": "/tmp/runs/fastsac_async_s3_x", "walking_reached": True,
                                            "time_to_walking_s": 99.0, "env_steps_at_walking": 7}]}))
    out = tmp_path / "runs.json"
    res = subprocess.run([sys.executable, SCRIPT, "--out", str(out), f"abc,base,8,{ttt},{metrics}"],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    rec = json.loads(out.read_text())["records"][0]
    assert (rec["commit"], rec["variant"], rec["seed"], rec["time_to_walking_s"]) == ("abc", "base", 3, 99.0)
    window, whole = rec["window"], rec["from_start"]
    assert abs(window["calls_per_s"] - 20.0) < 0.05 and abs(window["grad_steps_per_s"] - 160.0) < 0.5
    assert window["dispatch_ms"] == 30.0 and window["fetch_ms"] == 10.0  # 40-100 s at 30 ms, 100-115 at 20
    assert whole["calls"] == 1601 and whole["dispatch_ms"] == 30.0  # 40-120 s: 1200 calls at 30 ms, 400 at 20
    assert "| abc | base | 3 | 99.0 |" in res.stdout
    bad = subprocess.run([sys.executable, SCRIPT, "--out", str(out), "abc,base"], capture_output=True, text=True)
    assert bad.returncode == 2 and "commit,variant,U,TTT_JSON,METRICS_DIR" in bad.stderr


def test_hardware_plot_counts_a_run_that_did_not_walk_at_its_budget(tmp_path):
    sys.path.insert(0, os.path.join(ROOT, "bench"))
    import plot_hardware

    ttt = tmp_path / "ttt.json"
    ttt.write_text(json.dumps({"records": [
        {"walking_reached": True, "time_to_walking_s": 90.0, "max_seconds": 140.0},
        {"walking_reached": False, "time_to_walking_s": None, "max_seconds": 140.0}]}))
    assert plot_hardware.walking_times(str(ttt)) == [(90.0, True), (140.0, False)]
    script = os.path.join(ROOT, "bench", "plot_hardware.py")
    res = subprocess.run([sys.executable, script, "--out", str(tmp_path / "p.png"), str(ttt)],
                         capture_output=True, text=True)
    assert res.returncode == 2 and "LABEL=RECORDS_JSON" in res.stderr
    res = subprocess.run([sys.executable, script, "--out", str(tmp_path / "p.png"), f"1 GPU={ttt}"],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "p.png").stat().st_size > 1000


def test_calls_from_half_second_bins_and_from_the_logged_rate_of_older_bins(tmp_path):
    sys.path.insert(0, os.path.join(ROOT, "bench"))
    import gzip

    from compact_metrics import bin_by_wall

    metrics = tmp_path / "metrics"
    metrics.mkdir()
    # 20 calls/s from 30 s to 120 s; the trainer logs its own rate as 19 (a rate it smooths: not the row count)
    rows = [{"step": i, "time/wall_s": 30 + 0.05 * i, "perf/update_s": 0.01, "perf/learner_updates_per_s": 19.0}
            for i in range(1801)]
    raw = tmp_path / "raw.jsonl"
    raw.write_text("".join(json.dumps(r) + "\n" for r in rows))
    bin_by_wall(str(raw), str(tmp_path / "binned.jsonl.gz"), 0.5)
    binned = [json.loads(line) for line in gzip.open(tmp_path / "binned.jsonl.gz", "rt")]
    legacy = [{k: v for k, v in r.items() if k != "compact/rows"} for r in binned]
    ttt = tmp_path / "ttt.json"
    records = []
    for name, data in (("binned", binned), ("legacy", legacy)):
        (metrics / f"{name}.jsonl").write_text("".join(json.dumps(r) + "\n" for r in data))
        records.append({"config": name, "seed": 0, "max_seconds": 120.0, "logdir": f"/tmp/runs/{name}",
                        "walking_reached": False})
    ttt.write_text(json.dumps({"records": records}))
    out = tmp_path / "runs.json"
    res = subprocess.run([sys.executable, SCRIPT, "--out", str(out), f"abc,base,8,{ttt},{metrics}"],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    binned_rec, legacy_rec = (r["window"] for r in json.loads(out.read_text())["records"])
    assert binned_rec["calls_source"] == "rows" and abs(binned_rec["calls_per_s"] - 20.0) < 0.3
    assert legacy_rec["calls_source"] == "logged" and legacy_rec["calls_per_s"] == 19.0
