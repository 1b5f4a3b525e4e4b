"""What the terrain curriculum's two demotion rules do with a walker that delivers a fraction of its commands
(issue 33): the Go1 task's command sampling (``command_a`` ranges, resampled after exponential times of mean
``command_resample_mean_s``) over whole episodes, integrated kinematically (no physics) by
``tasks.curriculum.advance_commanded_path``. A walker reaching ``f`` x the commanded displacement is promoted past
half a cell (4 m), demoted by legged_gym's rule (less than half the path's length) or by this project's (less than
half the path's reach); writes JSON::

    python bench/commanded_reach.py --out bench/results/local/phase3/commanded_reach.json
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.machine import host_info, write_json  # noqa: E402
from tasks import curriculum  # noqa: E402
from tasks.go1_joystick import Go1JoystickConfig  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episodes", type=int, default=20000)
    ap.add_argument("--fractions", type=float, nargs="+", default=[1.0, 0.8, 0.6, 0.4])
    ap.add_argument("--cell", type=float, default=8.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    if args.episodes < 1 or args.cell <= 0:
        print("error: --episodes >= 1 and --cell > 0", file=sys.stderr)
        return 2
    c, r, n = Go1JoystickConfig(), np.random.default_rng(args.seed), args.episodes
    a, dt = np.array(c.command_a), c.ctrl_dt
    command = r.uniform(-a, a, (n, 3))
    next_in = np.round(r.exponential(c.command_resample_mean_s, n) / dt)
    path, heading, length = np.zeros((n, 2)), np.zeros(n), np.zeros(n)
    for _ in range(c.episode_length):
        next_in -= 1
        due = next_in <= 0
        command[due] = r.uniform(-a, a, (int(due.sum()), 3))
        next_in[due] = np.round(r.exponential(c.command_resample_mean_s, int(due.sum())) / dt)
        path, heading = curriculum.advance_commanded_path(path, heading, command, dt)
        length += np.linalg.norm(command[:, :2], axis=1) * dt
    reach = np.linalg.norm(path, axis=1)
    rows = []
    for f in args.fractions:
        walked = f * reach
        up = walked > args.cell / 2
        rows.append({"fraction": f, "promoted": float(up.mean()),
                     "demoted_path_length": float(((walked < length / 2) & ~up).mean()),
                     "demoted_reach": float(((walked < reach / 2) & ~up).mean())})
        print(f"{f:.0%} of the commanded displacement: promoted {rows[-1]['promoted']:.3f}, demoted by the path's "
              f"length {rows[-1]['demoted_path_length']:.3f}, by its reach {rows[-1]['demoted_reach']:.3f}")
    write_json(args.out, {"machine": host_info(), "episodes": n, "cell": args.cell, "seed": args.seed,
                          "median_reach_m": float(np.median(reach)), "median_length_m": float(np.median(length)),
                          "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
