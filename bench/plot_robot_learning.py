"""Success rate against robot-minutes for the Franka runs (issue 32): one panel per task, one line per run, coloured
by method (RLPD from images, RLPD from state, SAC from scratch); the runs' own evaluations (``eval/success_rate`` in
their metrics, 4 episodes each).

    python bench/plot_robot_learning.py --out docs/robot_learning.png \\
        "RLPD, images=bench/results/h100/phase3/franka_images_7e25bb7/rlpd_peg_images_s*.jsonl.gz" ...

Each argument is ``LABEL=GLOB`` and names its task by ``peg`` or ``pick`` in the file names; robot-minutes = env
steps / 600 (10 Hz control). Needs matplotlib (the ``dev`` extra).
"""

from __future__ import annotations

import argparse
import glob
import gzip
import json
import sys

TASKS = {"peg": "peg insertion", "pick": "pick-and-place"}
STEPS_PER_ROBOT_MINUTE = 600.0  # 10 Hz control


def curve(path: str) -> tuple[list[float], list[float]]:
    """(robot-minutes, success rate) of every evaluation row in a metrics file (.jsonl or .jsonl.gz)."""
    opener = gzip.open if path.endswith(".gz") else open
    xs, ys = [], []
    with opener(path, "rt") as f:
        for line in f:
            row = json.loads(line)
            if "eval/success_rate" in row:
                xs.append(row["step"] / STEPS_PER_ROBOT_MINUTE)
                ys.append(row["eval/success_rate"])
    return xs, ys


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("series", nargs="+", help="LABEL=GLOB")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(TASKS), figsize=(10, 5.2), sharey=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    drawn = 0
    for i, spec in enumerate(args.series):
        label, sep, pattern = spec.partition("=")
        if not sep:
            print(f"{spec!r}: give LABEL=GLOB", file=sys.stderr)
            sys.exit(2)
        paths = sorted(glob.glob(pattern))
        if not paths:
            print(f"{label}: no file matches {pattern!r}", file=sys.stderr)
            sys.exit(2)
        for path in paths:
            task = next((t for t in TASKS if t in path.rsplit("/", 1)[-1]), None)
            if task is None:
                continue
            ax = axes[list(TASKS).index(task)]
            xs, ys = curve(path)
            seen = label in ax.get_legend_handles_labels()[1]
            ax.plot(xs, ys, marker=".", color=colours[i % len(colours)], label=None if seen else label, alpha=0.8)
            drawn += 1
    for ax, title in zip(axes, TASKS.values()):
        ax.set_title(f"Franka {title}")
        ax.set_xlabel("robot-minutes")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)  # below: the curves stay seen
        ax.set_xlim(left=0)
    axes[0].set_ylabel("success rate (4 episodes)")
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"{drawn} runs -> {args.out}")


if __name__ == "__main__":
    main()
