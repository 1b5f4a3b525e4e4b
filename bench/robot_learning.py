"""Robot-learning results (issue 32): one record per evaluation in a JSON file.

    python bench/robot_learning.py --out bench/results/h100/phase3/robot_learning.json --commit abc1234 DIR [DIR ...]
        [--machine "2x H200 + 32 cores"]

Each DIR holds ``bench/franka_gpu_runs.sh``'s outputs; every ``<job>[_<arm>]_eval40_<step>.json`` in it (``python -m
unilab_jax.play``'s report on the checkpoint of env step ``<step>``, evaluated on ``arm``: ``franka`` unless the
name says ``ur5e``) becomes a record: ``arm``, ``task``, ``algo``,
``episodes`` and ``success`` (the success rate) from the report; ``observation`` (``images`` for the ``*_images*``
jobs, else ``state``), ``asymmetric`` (``*_asym_*``: the critic also reads the privileged state) and ``seed``
(``_sN``) from the job's name; ``reward`` (``dense``: the task's potential-based shaping, the peg insertion jobs and
``*_dense*`` and ``*_gate*``; else ``success``: 1 on success only), ``interventions`` (``*_gate*``: an operator
corrected the training episodes; the evaluations run without it); ``env_steps``; ``robot_minutes`` = env steps /
(control rate x 60), the control rate being the report's ``fps``; an empty or unfinished report (an evaluation
stopped by a deadline) is skipped with a message. A record replaces the file's record of the same job, arm and env
step (a record without ``arm`` is the Franka's). ``--machine`` adds a ``machine`` field (records without one are the
H100 + 16-core machine's).
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import re
import sys

REPORT = re.compile(r"^(?P<job>.+_s(?P<seed>\d+))(?:_(?P<arm>ur5e))?_eval40_(?P<step>\d+)\.json$")


def reward_of(job: str) -> str:
    """``dense`` for the jobs of ``bench/franka_gpu_runs.sh`` that train with the shaped reward, else ``success``."""
    return "dense" if "_peg" in job or "_dense" in job or "_gate" in job else "success"


def records(folder: str, commit: str, machine: str = "") -> list[dict]:
    """The records of the evaluation reports in ``folder``."""
    out = []
    for path in sorted(glob.glob(os.path.join(folder, "*_eval40_*.json"))):
        m = REPORT.match(os.path.basename(path))
        if m is None:
            continue
        try:
            with open(path) as f:
                report = json.load(f)
        except json.JSONDecodeError:  # an evaluation stopped before it wrote its report (the call's deadline)
            print(f"skipped {path}: not a finished report", file=sys.stderr)
            continue
        job, step = m["job"], int(m["step"])
        out.append({"job": job, "arm": m["arm"] or "franka", "task": report["task"], "algo": report["algo"],
                    "observation": "images" if "_images" in job else "state", "asymmetric": "_asym_" in job,
                    "reward": reward_of(job), "interventions": "_gate" in job,
                    "seed": int(m["seed"]), "env_steps": step, "robot_minutes": step / (report["fps"] * 60.0),
                    "episodes": int(report["episodes"]), "success": report["success_rate"], "commit": commit})
        if machine:
            out[-1]["machine"] = machine
    return out


def merge(existing: list[dict], new: list[dict]) -> list[dict]:
    """``existing`` with ``new`` added, a new record replacing one of the same job, arm and env step."""
    key = lambda r: (r["job"], r.get("arm", "franka"), r["env_steps"])
    keys = {key(r) for r in new}
    return [r for r in existing if key(r) not in keys] + new


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--out", required=True)
    ap.add_argument("--commit", required=True)
    ap.add_argument("--machine", default="", help="the GPU machine, when not the H100 + 16 cores")
    args = ap.parse_args()
    new = [r for folder in args.folders for r in records(folder, args.commit, args.machine)]
    if not new:
        print(f"no <job>_eval40_<step>.json report in {args.folders}", file=sys.stderr)
        sys.exit(2)
    existing = json.load(open(args.out)) if os.path.exists(args.out) else []
    merged = merge(existing, new)
    with open(args.out, "w") as f:
        json.dump(merged, f, indent=1)
    for r in new:
        print(f"{r['job']:28s} {r['arm']:6s} {r['robot_minutes']:6.1f} robot-min  success {r['success']:.3f} "
              f"({r['episodes']} episodes)")


if __name__ == "__main__":
    main()
