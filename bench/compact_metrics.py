"""Compacts a run's metrics.jsonl for bench/results: every evaluation row and one training row per 500 env steps
(key scalars), gzipped. Per-episode task metrics (``episode/late_fraction``, ``episode/intervention_rate``: logged
only on rows where episodes ended) are kept as their mean over the rows since the previous kept row that have them,
so a window whose kept row ended no episode still reports them.

    python bench/compact_metrics.py RUN/metrics.jsonl OUT.jsonl.gz

``--wall_bin S`` (the locomotion runs, whose trainers log a row per learner call: ~16 MB gzipped in 10 minutes)
keeps every scalar instead: the training rows of each S seconds of ``time/wall_s`` become one row of their means
(``step`` and ``time/wall_s`` those of the bin's last row, ``compact/rows`` how many rows it stands for: one per
learner call, what ``bench/learner_runs.py`` counts), evaluation rows as written; the terrain-level curves
of ``bench/terrain_curves.py`` (20 s windows) move by < 0.03 at S = 0.5. The source may be gzipped.
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


def bin_by_wall(src: str, dst: str, seconds: float) -> int:
    """Evaluation rows as written, training rows averaged over ``seconds`` of ``time/wall_s``; returns the rows."""
    out: list[dict] = []
    group: list[dict] = []

    def flush() -> None:
        if group:
            keys = dict.fromkeys(k for r in group for k in r)
            mean = {k: sum(r[k] for r in group if k in r) / sum(1 for r in group if k in r) for k in keys}
            out.append({**mean, "step": group[-1]["step"], "time/wall_s": group[-1]["time/wall_s"],
                        "compact/rows": len(group)})
            group.clear()

    current = None
    with (gzip.open(src, "rt") if src.endswith(".gz") else open(src)) as f:
        for line in f:
            r = json.loads(line)
            if "time/wall_s" not in r or any(k.startswith("eval/") for k in r):
                flush()
                out.append(r)
                current = None
                continue
            b = int(r["time/wall_s"] // seconds)
            if b != current:
                flush()
                current = b
            group.append(r)
    flush()
    with gzip.open(dst, "wt") as f:
        f.writelines(json.dumps(r) + "\n" for r in out)
    return len(out)


if __name__ == "__main__":
    if sys.argv[1] == "--wall_bin":
        print(sys.argv[4], bin_by_wall(sys.argv[3], sys.argv[4], float(sys.argv[2])), "rows")
    else:
        print(sys.argv[2], compact(sys.argv[1], sys.argv[2]), "rows")
