"""Compacts a run's metrics.jsonl for bench/results: every evaluation row and one training row per 500 env steps
(key scalars), gzipped. Per-episode task metrics (``episode/late_fraction``, ``episode/intervention_rate``: logged
only on rows where episodes ended) are kept as their mean over the rows since the previous kept row that have them,
so a window whose kept row ended no episode still reports them.

    python bench/compact_metrics.py RUN/metrics.jsonl OUT.jsonl.gz
"""

import gzip
import json
import sys

KEEP = ("step", "time/wall_s", "episode/success_rate", "episode/return", "perf/env_steps_per_s", "loss/q_std",
        "loss/critic", "loss/alpha")
WINDOW_MEANS = ("episode/late_fraction", "episode/intervention_rate")


def compact(src: str, dst: str, every: int = 500) -> int:
    out, next_step, pending = [], 0, {}
    with open(src) as f:
        for line in f:
            r = json.loads(line)
            if any(k.startswith("eval/") for k in r):
                out.append(r)
                continue
            for k in WINDOW_MEANS:
                if k in r:
                    pending.setdefault(k, []).append(r[k])
            if r.get("step", -1) >= next_step:
                row = {k: v for k, v in r.items() if k in KEEP or k.startswith("perf/utd")}
                row.update({k: sum(v) / len(v) for k, v in pending.items()})
                out.append(row)
                pending, next_step = {}, (r["step"] // every + 1) * every
    with gzip.open(dst, "wt") as f:
        f.writelines(json.dumps(r) + "\n" for r in out)
    return len(out)


if __name__ == "__main__":
    print(sys.argv[2], compact(sys.argv[1], sys.argv[2]), "rows")
