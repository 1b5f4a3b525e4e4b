"""Compacts a run's metrics.jsonl for bench/results: every evaluation row and one training row per 500 env steps
(key scalars), gzipped.

    python bench/compact_metrics.py RUN/metrics.jsonl OUT.jsonl.gz
"""

import gzip
import json
import sys

KEEP = ("step", "time/wall_s", "episode/success_rate", "episode/return", "episode/late_fraction",
        "perf/env_steps_per_s", "loss/q_std", "loss/critic", "loss/alpha")


def compact(src: str, dst: str, every: int = 500) -> int:
    out, next_step = [], 0
    with open(src) as f:
        for line in f:
            r = json.loads(line)
            if any(k.startswith("eval/") for k in r):
                out.append(r)
            elif r.get("step", -1) >= next_step:
                out.append({k: v for k, v in r.items() if k in KEEP or k.startswith("perf/utd")})
                next_step = (r["step"] // every + 1) * every
    with gzip.open(dst, "wt") as f:
        f.writelines(json.dumps(r) + "\n" for r in out)
    return len(out)


if __name__ == "__main__":
    print(sys.argv[2], compact(sys.argv[1], sys.argv[2]), "rows")
