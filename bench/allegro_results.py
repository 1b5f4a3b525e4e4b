"""Allegro in-hand rotation results (issue 37): one record per setting, role and seed in a JSON file.

    python bench/allegro_results.py --out bench/results/h100/phase3/allegro.json --setting base --seed 0 \\
        --commit abc1234 --run teacher=runs/hora_s0/teacher --run student=runs/hora_s0/student --run ppo=runs/ppo_s0
    python bench/allegro_results.py --out bench/results/h100/phase3/allegro.json --report

A record (``ROLES``: teacher | student | ppo) is read from the run's logdir: its last evaluation (``summary.json``,
the trainer's final one) gives ``rotation_rad_s`` (with ``rotation_rad_s_se``, its standard error over the
episodes, where the run logged it), ``rotation_episode_rad_s`` (the yaw turned over the whole time limit per
second, 0 after a fall: ``tasks/allegro_metric.py``; None for runs from before it was logged), ``time_to_fall``
(fraction of the episode), ``rotate_reward`` (mean per-step rotation term) and ``eval_episodes``; ``env_steps``,
``wall_s`` and ``interrupted`` (stopped by a signal or time limit before its step budget) are the run's (a run that
ended without ``summary.json``: its last evaluation row and its last training row's step and wall time,
``interrupted`` and ``no_summary`` true); ``curve``
lists every evaluation as [env steps, rotation rate, time to fall]; ``final_evals`` the large evaluations of its last
checkpoints where the logdir holds them (``final_eval_<step>.json``: ``python -m unilab_jax.play --checkpoint <step>
--episodes N``'s report, written there by ``bench/p37_allegro.sh FINAL_EVAL=N``), each {checkpoint, episodes,
rotation_rad_s, rotation_rad_s_se, time_to_fall}, and ``neighbour_gap_rad_s``, the rate difference of the last two
of them (the issue asks for evaluations large enough that neighbouring checkpoints agree within 0.03 rad/s); the
report then judges the role by its last large evaluation. A record replaces the file's record of the same
(setting, role, seed). ``--report`` prints, per setting and role, the mean over seeds against the goal
(teacher >= 0.2 rad/s with time to fall >= 0.8; student >= 0.8 of its teacher's rate). ``--png PATH`` draws every
record's curve (rotation rate and time to fall against env steps; needs matplotlib, the ``dev`` extra):

    python bench/allegro_results.py --out bench/results/h100/phase3/allegro.json --png docs/allegro_curves.png
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys

ROLES = ("teacher", "student", "ppo")
GOAL_RATE, GOAL_TTF, GOAL_STUDENT = 0.2, 0.8, 0.8


def read_run(logdir: str) -> dict:
    """The record's measured fields from a run's ``summary.json`` and ``metrics.jsonl``."""
    curve, last_eval, last_row = [], None, {}
    with open(os.path.join(logdir, "metrics.jsonl")) as f:
        for line in f:
            row = json.loads(line)
            if "time/wall_s" in row:
                last_row = row
            if "eval/rotation_rate" in row:
                curve.append([row["step"], row["eval/rotation_rate"], row["eval/time_to_fall"]])
                last_eval = row
    path = os.path.join(logdir, "summary.json")
    if os.path.exists(path):
        with open(path) as f:
            summary = json.load(f)
    elif last_eval is not None:  # a run that ended without its summary: its last evaluation, flagged
        summary = {**last_eval, "env_steps": last_row.get("step", last_eval["step"]),
                   "wall_s": last_row.get("time/wall_s", last_eval.get("eval/wall_s")),
                   "interrupted": True, "no_summary": True}
    else:
        raise ValueError(f"{logdir}: no summary.json and no evaluation in metrics.jsonl")
    if "eval/rotation_rate" not in summary:
        raise ValueError(f"{logdir}: summary.json has no final evaluation (eval/rotation_rate)")
    finals = []
    for name in os.listdir(logdir):
        m = re.fullmatch(r"final_eval_(\d+)\.json", name)
        if m:
            with open(os.path.join(logdir, name)) as f:
                rep = json.load(f)
            finals.append({"checkpoint": int(m[1]), "episodes": rep["episodes"], "rotation_rad_s": rep["rotation_rate"],
                           "rotation_rad_s_se": rep["rotation_rate_se"], "time_to_fall": rep["time_to_fall"]})
    finals.sort(key=lambda e: e["checkpoint"])
    gap = abs(finals[-1]["rotation_rad_s"] - finals[-2]["rotation_rad_s"]) if len(finals) > 1 else None
    return {"rotation_rad_s": summary["eval/rotation_rate"],
            "rotation_rad_s_se": summary.get("eval/rotation_rate_se"),
            "rotation_episode_rad_s": summary.get("eval/rotation_episode"),
            "time_to_fall": summary["eval/time_to_fall"], "rotate_reward": summary["eval/rotate_reward"],
            "eval_episodes": summary.get("eval/episodes"), "env_steps": summary["env_steps"],
            "wall_s": summary["wall_s"], "interrupted": summary.get("interrupted"), "curve": curve,
            **({"no_summary": True} if summary.get("no_summary") else {}),
            **({"final_evals": finals, "neighbour_gap_rad_s": gap} if finals else {})}


def merge(records: list[dict], new: list[dict]) -> list[dict]:
    """``records`` with each of ``new`` replacing the one of the same (setting, role, seed), in a stable order."""
    key = lambda r: (r["setting"], r["role"], r["seed"])
    out = {key(r): r for r in records}
    out.update({key(r): r for r in new})
    return sorted(out.values(), key=lambda r: (r["setting"], ROLES.index(r["role"]), r["seed"]))


def report(records: list[dict]) -> list[str]:
    """One line per (setting, role): seeds, mean rate, time to fall, and the goal's verdict."""
    lines, groups = [], {}
    for r in records:
        groups.setdefault((r["setting"], r["role"]), []).append(r)
    def judged(r: dict, k: str) -> float:  # the last large evaluation's value where the record has one
        return r["final_evals"][-1][k] if r.get("final_evals") else r[k]

    mean = lambda rs, k: sum(judged(r, k) for r in rs) / len(rs)
    for (setting, role), rs in groups.items():
        rate, ttf = mean(rs, "rotation_rad_s"), mean(rs, "time_to_fall")
        if role == "student" and (setting, "teacher") in groups:
            teacher = mean(groups[(setting, "teacher")], "rotation_rad_s")
            verdict = f"{rate / teacher:.2f}x the teacher (goal >= {GOAL_STUDENT})" if teacher else "teacher at 0"
        else:
            met = rate >= GOAL_RATE and ttf >= GOAL_TTF
            verdict = f"goal {'met' if met else 'missed'} (>= {GOAL_RATE} rad/s, time to fall >= {GOAL_TTF})"
        rates = ", ".join(f"{judged(r, 'rotation_rad_s'):.3f}" for r in rs)
        steps, wall = sum(r["env_steps"] for r in rs) / len(rs), sum(r["wall_s"] for r in rs) / len(rs)
        final = [r for r in rs if r.get("final_evals")]
        judged_by = (f" (last checkpoint, {min(r['final_evals'][-1]['episodes'] for r in final):.0f}+ episodes)"
                     if len(final) == len(rs) else "")
        gaps = [r["neighbour_gap_rad_s"] for r in final if r.get("neighbour_gap_rad_s") is not None]
        gap = f", neighbouring checkpoints {max(gaps):.3f} rad/s apart at most" if gaps else ""
        lines.append(f"{setting:16s} {role:8s} seeds {len(rs)}: rate {rate:.3f} rad/s ({rates}){judged_by}, time to "
                     f"fall {ttf:.2f}, {steps / 1e6:.1f}M steps, {wall:.0f} s{gap}; {verdict}")
    return lines


def plot(records: list[dict], path: str) -> int:
    """The records' curves in two panels (rotation rate, time to fall), a colour per (setting, role), a line per
    seed; the goal's lines dashed. Returns the number of curves drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_rate, ax_ttf) = plt.subplots(1, 2, figsize=(10, 4.6))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    groups = list(dict.fromkeys((r["setting"], r["role"]) for r in records))
    drawn = 0
    for r in records:
        if not r.get("curve"):
            continue
        steps, rate, ttf = zip(*r["curve"], strict=True)
        i = groups.index((r["setting"], r["role"]))
        label = f"{r['role']} ({r['setting']})" if r["seed"] == min(
            q["seed"] for q in records if (q["setting"], q["role"]) == groups[i]) else None
        x = [s / 1e6 for s in steps]
        ax_rate.plot(x, rate, marker=".", color=colours[i % len(colours)], label=label, alpha=0.8)
        ax_ttf.plot(x, ttf, marker=".", color=colours[i % len(colours)], alpha=0.8)
        drawn += 1
    for ax, goal, name in ((ax_rate, GOAL_RATE, "rotation rate (rad/s)"), (ax_ttf, GOAL_TTF, "time to fall (episode)")):
        ax.axhline(goal, color="grey", linestyle="--", linewidth=1)
        ax.set_xlabel("env steps of the role (M)")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
        ax.set_xlim(left=0)
        ax.set_ylim(bottom=0)
    # below the panels, where it covers no curve
    handles, labels = ax_rate.get_legend_handles_labels()
    columns = 4
    fig.legend(handles, labels, loc="lower center", ncol=columns, fontsize=8, frameon=False)
    rows = -(-len(labels) // columns)
    fig.suptitle("Allegro in-hand rotation: evaluations per seed", fontsize=10)
    fig.tight_layout(rect=(0, 0.05 * rows, 1, 1))
    fig.savefig(path, dpi=110)
    return drawn


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="the results JSON (created if absent)")
    parser.add_argument("--run", action="append", default=[], help="ROLE=LOGDIR (ROLE: teacher, student, ppo)")
    parser.add_argument("--setting", default="base", help="the name of the settings the runs used")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--commit", default="unknown")
    parser.add_argument("--machine", default="H100 + 16 cores")
    parser.add_argument("--command", default="", help="the command the runs were made with")
    parser.add_argument("--report", action="store_true", help="print the file's table")
    parser.add_argument("--png", default="", help="draw the file's curves into this PNG")
    args = parser.parse_args(argv)
    records = []
    if os.path.isfile(args.out):
        with open(args.out) as f:
            records = json.load(f)["records"]
    new = []
    for item in args.run:
        role, _, logdir = item.partition("=")
        if role not in ROLES or not logdir:
            print(f"error: --run {item!r}: expected ROLE=LOGDIR with ROLE one of {ROLES}", file=sys.stderr)
            return 2
        try:
            measured = read_run(logdir)
        except (OSError, ValueError, KeyError) as e:
            print(f"error: --run {item!r}: {e}", file=sys.stderr)
            return 2
        new.append({"setting": args.setting, "role": role, "seed": args.seed, **measured, "commit": args.commit,
                    "machine": args.machine, "command": args.command})
    if new:
        records = merge(records, new)
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, "w") as f:
            json.dump({"records": records}, f, indent=1)
        print(f"{len(new)} record(s) -> {args.out}")
    if args.report:
        print("\n".join(report(records)))
    if args.png:
        print(f"{plot(records, args.png)} curves -> {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
