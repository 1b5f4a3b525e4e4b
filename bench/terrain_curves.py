"""Mean terrain level against time of rough-terrain runs (issue 33's curves), from their ``metrics.jsonl``.

Reads every ``<config>_s<seed>_<date>.jsonl`` (or ``.jsonl.gz``, as ``bench/p33_terrain.sh`` leaves them) in the
given folders or files, keeps the training rows that log ``episode/terrain_level`` (the mean level of the episodes
that ended since the previous row: ``tasks/rough.py``; on the GPU machine a row every ~30 ms holds 1-7 episodes, so
one row says little about the population), averages them over a trailing window of ``WINDOW_S`` (one episode's
duration: every robot ends about one episode in it), thinned to at most ``--points`` per run, and writes
``{run: {"wall_s": [...], "step": [...], "terrain_level": [...], "terrain_level_top": k, "window_s": w}}`` as JSON;
``--png`` also plots them (matplotlib, the dev extra) with the goal line at 70% of the top level::

    python bench/terrain_curves.py bench/results/h100/phase3/terrain/metrics --out curves.json --png curves.png

A run is named ``<config>_s<seed>``, or ``--label STEM=TEXT`` names the run of the file ``STEM.jsonl[.gz]`` (runs of
one configuration and seed at several commits: each its own curve; docs/terrain_levels.png is drawn so, the labels
in docs/dev/GPU_RUNS.md).
"""

from __future__ import annotations

import argparse
import glob
import gzip
import json
import os
import sys
from typing import Any

PREFIX = "episode/terrain_level_"
GOAL_FRACTION = 0.7  # issue 33: the mean terrain level reaches >= 70% of the top level
WINDOW_S = 20.0  # the rough tasks' episode: 1000 control steps at 50 Hz


def windowed(rows: list[dict[str, Any]], window_s: float = WINDOW_S) -> list[tuple[dict[str, Any], float]]:
    """(row, mean level) for each training row from ``window_s`` after the first on: the mean of the
    ``episode/terrain_level`` of the rows logged in the trailing ``window_s`` seconds of wall time (``time/wall_s``),
    the row's own included; rows in wall-time order."""
    out, total, lo = [], 0.0, 0
    start = rows[0]["time/wall_s"] if rows else 0.0
    for hi, r in enumerate(rows):
        total += r["episode/terrain_level"]
        while rows[lo]["time/wall_s"] <= r["time/wall_s"] - window_s:
            total -= rows[lo]["episode/terrain_level"]
            lo += 1
        if r["time/wall_s"] >= start + window_s:
            out.append((r, total / (hi - lo + 1)))
    return out


def _open(path: str):
    return gzip.open(path, "rt") if path.endswith(".gz") else open(path)


def curve(path: str, points: int = 400) -> dict[str, Any]:
    """The terrain-level curve of one run's metrics file (``points`` rows at most, evenly thinned, last row kept)."""
    rows = []
    with _open(path) as f:
        for line in f:
            r = json.loads(line)
            if "episode/terrain_level" in r and "time/wall_s" in r:
                rows.append(r)
    smooth = windowed(rows)
    if len(smooth) > points:
        keep = sorted({round(i * (len(smooth) - 1) / (points - 1)) for i in range(points)})
        smooth = [smooth[i] for i in keep]
    keys = rows[0].keys() if rows else ()
    top = max((int(k[len(PREFIX):]) for k in keys if k.startswith(PREFIX) and k[len(PREFIX):].isdigit()), default=None)
    return {"wall_s": [round(r["time/wall_s"], 1) for r, _ in smooth], "step": [r["step"] for r, _ in smooth],
            "terrain_level": [round(m, 3) + 0.0 for _, m in smooth],  # + 0.0: no -0.0 from the running sum
            "terrain_level_top": top, "window_s": WINDOW_S}


def run_name(path: str, labels: dict[str, str] | None = None) -> str:
    """``labels[stem]``, else ``<config>_s<seed>`` of ``<config>_s<seed>_<date>_<time>.jsonl[.gz]``."""
    stem = os.path.basename(path).split(".jsonl")[0]
    if labels and stem in labels:
        return labels[stem]
    return stem.rsplit("_", 2)[0] if stem.count("_") >= 3 else stem


def find(paths: list[str]) -> list[str]:
    out = []
    for p in paths:
        out += sorted(glob.glob(os.path.join(p, "*.jsonl*"))) if os.path.isdir(p) else [p]
    return out


def plot(curves: dict[str, dict[str, Any]], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for name, c in sorted(curves.items()):
        ax.plot(c["wall_s"], c["terrain_level"], label=name, linewidth=1.2)
    tops = {c["terrain_level_top"] for c in curves.values() if c["terrain_level_top"]}
    for top in tops:
        ax.axhline(GOAL_FRACTION * top, color="grey", linestyle="--", linewidth=0.8)
    ax.set_xlabel("wall time from process start (s)")
    ax.set_ylabel(f"mean terrain level (episodes ended in {WINDOW_S:.0f} s)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("paths", nargs="+", help="metrics files or folders of them")
    ap.add_argument("--out", required=True, help="the curves' JSON")
    ap.add_argument("--png", default="", help="also plot them here (needs matplotlib)")
    ap.add_argument("--points", type=int, default=400)
    ap.add_argument("--label", action="append", default=[], metavar="STEM=TEXT",
                    help="name the run of metrics file STEM.jsonl[.gz] TEXT (repeatable)")
    args = ap.parse_args(argv)
    files = find(args.paths)
    labels = dict(item.split("=", 1) for item in args.label if "=" in item)
    error = ("no metrics files found" if not files else "--points must be at least 2" if args.points < 2
             else "--label takes STEM=TEXT" if len(labels) != len(args.label) else "")
    if error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    curves = {run_name(p, labels): curve(p, args.points) for p in files}
    curves = {k: v for k, v in curves.items() if v["step"]}
    with open(args.out, "w") as f:
        json.dump(curves, f)
    print(f"{args.out}: {len(curves)} runs")
    for k, c in curves.items():
        print(f"  {k}: max mean level {max(c['terrain_level']):.2f} of {c['terrain_level_top']}")
    if args.png:
        plot(curves, args.png)
    return 0


if __name__ == "__main__":
    sys.exit(main())
