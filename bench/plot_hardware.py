"""Time to walking against hardware (issue 31): one column per setup, every seed's time to walking as a point and
their mean as a bar, from ``bench/time_to_target.py`` records (``bench/p31_whole.sh`` writes one file per setup).

    python bench/plot_hardware.py --out docs/hardware_walking.png --title "FastSAC Go1, 2x H200 host" \\
        "1 GPU + 16 cores=bench/results/h200x2/phase3/whole_cb07ac3/ttt_gpu1_cores16.json" ...

Each argument is ``LABEL=RECORDS_JSON``. A run that did not walk within its budget is drawn at the budget, hollow, and
counts at the budget in the mean (a lower bound, marked with ">="). Needs matplotlib (the ``dev`` extra).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys


def walking_times(path: str) -> list[tuple[float, bool]]:
    """(seconds, walked) per record: the time to walking, or the budget of a run that did not walk."""
    return [(r["time_to_walking_s"], True) if r.get("walking_reached") else (r["max_seconds"], False)
            for r in json.load(open(path))["records"]]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("setups", nargs="+", help="LABEL=RECORDS_JSON")
    ap.add_argument("--title", default="")
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    columns = []
    for spec in args.setups:
        label, sep, path = spec.partition("=")
        if not sep or not label:
            ap.error(f"each setup is LABEL=RECORDS_JSON, got {spec!r}")
        try:
            times = walking_times(path)
        except (OSError, ValueError, KeyError) as e:
            print(f"error: {path}: {e}", file=sys.stderr)
            sys.exit(2)
        if not times:
            print(f"error: {path} holds no records", file=sys.stderr)
            sys.exit(2)
        columns.append((label, times))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(1.9 * len(columns) + 1.5, 3.6))
    for i, (_, times) in enumerate(columns):
        mean = statistics.mean(t for t, _ in times)
        lower = not all(w for _, w in times)
        ax.bar(i, mean, width=0.6, color="#9ecae1")
        seeds = f"{len(times)} seed{'s' if len(times) > 1 else ''}"
        ax.text(i, max(mean, *(t for t, _ in times)) + 3, f"{'>=' if lower else ''}{mean:.0f} s ({seeds})",
                ha="center", va="bottom", fontsize=8)
        for j, (t, walked) in enumerate(times):
            ax.plot(i + 0.08 * (j - (len(times) - 1) / 2), t, "o", color="#08519c",
                    markerfacecolor="#08519c" if walked else "none")
    ax.set_xticks(range(len(columns)), [label for label, _ in columns], fontsize=8)
    ax.set_ylabel("time to walking (s, from process start)")
    ax.set_ylim(0, max(t for _, ts in columns for t, _ in ts) * 1.25)
    ax.set_title(args.title, fontsize=9)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
