"""In-run learner rates of off-policy time-to-walking runs: one record per run (seed) with its time to walking and
the learner's calls/s, gradient steps/s, dispatch and fetch milliseconds, read from ``bench/time_to_target.py``'s
records and the runs' metrics (``--metrics_dir``).

    python bench/learner_runs.py --out bench/results/h100/phase3/learner_runs.json \
        e0ea83d,base,8,/work/.device/3/ttt_base.json,/work/.device/3/metrics ...

Each RUN is ``commit,variant,U,TTT_JSON,METRICS_DIR`` (U: gradient steps per learner call). Rates are medians or
counts over the window [``--start``, ``--end``] seconds of each run's ``time/wall_s`` (the same window for every
run, so that runs of different lengths compare), and over the whole run from ``--start`` on. Calls are counted from
the rows (one per call; the half-second bins of ``bench/compact_metrics.py --wall_bin`` say how many calls each
holds); bins written before they did give the trainer's logged ``perf/learner_updates_per_s`` instead
(``calls_source``: ``rows`` or ``logged``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from machine import cpu_model  # noqa: E402

# Rows closer than this are one per learner call (60-100 calls/s); compacted bins are 0.5 s apart.
BINNED_GAP_S = 0.25


def _median(values: list[float]) -> float | None:
    values = sorted(v for v in values if v is not None)
    return values[len(values) // 2] if values else None


def rates(rows: list[dict], start: float, end: float, steps_per_call: int) -> dict:
    """Calls/s, gradient steps/s and the dispatch / fetch medians (ms) of the learner rows in [start, end] s."""
    calls = [r for r in rows if "perf/update_s" in r and start <= r["time/wall_s"] <= end]
    if len(calls) < 2:
        return {"calls": len(calls)}
    span = calls[-1]["time/wall_s"] - calls[0]["time/wall_s"]
    gap = _median([b["time/wall_s"] - a["time/wall_s"] for a, b in zip(calls, calls[1:])])
    if "compact/rows" in calls[0] or gap < BINNED_GAP_S:
        # a row per call, or bench/compact_metrics.py's bins with the count of calls each stands for
        n = sum(int(r.get("compact/rows", 1)) for r in calls)
        per_s, source = (n - calls[0].get("compact/rows", 1)) / span, "rows"
    else:  # bins written before they held their row count: the trainer's own rate, as logged
        n, per_s, source = None, _median([r.get("perf/learner_updates_per_s") for r in calls]), "logged"
        if per_s is None:
            return {"calls": None, "calls_source": "binned rows without a count or a logged rate"}
    return {"calls": n, "calls_source": source, "span_s": round(span, 1), "calls_per_s": round(per_s, 2),
            "grad_steps_per_s": round(per_s * steps_per_call, 1),
            "dispatch_ms": round(1e3 * _median([r["perf/update_s"] for r in calls]), 2),
            "fetch_ms": (round(1e3 * f, 2) if (f := _median([r.get("perf/fetch_s") for r in calls])) is not None
                         else None),
            "utd_reached": calls[-1].get("perf/utd")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="commit,variant,U,TTT_JSON,METRICS_DIR")
    ap.add_argument("--start", type=float, default=40.0)
    ap.add_argument("--end", type=float, default=115.0)
    ap.add_argument("--machine", default="H100 80GB HBM3 + 16 cores (nvidia-h100-x1)")
    ap.add_argument("--host_cpu", default=None, help="the runs' CPU model (default: this machine's)")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    records = []
    for spec in args.runs:
        try:
            commit, variant, u, ttt, metrics_dir = spec.split(",")
            steps_per_call = int(u)
        except ValueError:
            ap.error(f"RUN must be commit,variant,U,TTT_JSON,METRICS_DIR, got {spec!r}")
        for rec in json.load(open(ttt))["records"]:
            path = os.path.join(metrics_dir, os.path.basename(rec["logdir"]) + ".jsonl")
            rows = [json.loads(line) for line in open(path)]
            records.append({
                "commit": commit, "variant": variant, "config": rec["config"], "seed": rec["seed"],
                "updates_per_call": steps_per_call, "max_seconds": rec["max_seconds"],
                "walking_reached": rec["walking_reached"], "time_to_walking_s": rec.get("time_to_walking_s"),
                "env_steps_at_walking": rec.get("env_steps_at_walking"),
                "first_train_row_wall_s": rec.get("first_train_row_wall_s"),
                "startup": rec.get("startup", {}),
                "env_steps_per_s_median": rec.get("env_steps_per_s_median"),
                "window": rates(rows, args.start, args.end, steps_per_call),
                "from_start": rates(rows, args.start, float("inf"), steps_per_call)})
    out = {"machine": args.machine, "host_cpu": args.host_cpu or cpu_model(), "window_s": [args.start, args.end],
           "records": records}
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)
    print(f"| commit | variant | seed | walking s | calls/s | grad steps/s | dispatch ms | fetch ms | "
          f"calls/s ({args.start:.0f} s-end) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in records:
        w, a = r["window"], r["from_start"]
        walk = f"{r['time_to_walking_s']:.1f}" if r["walking_reached"] else f"not by {r['max_seconds']:.0f}"
        print(f"| {r['commit']} | {r['variant']} | {r['seed']} | {walk} | {w.get('calls_per_s')} | "
              f"{w.get('grad_steps_per_s')} | {w.get('dispatch_ms')} | {w.get('fetch_ms')} | {a.get('calls_per_s')} |")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
