"""Time to a walking policy (and to an evaluation return): heterogeneous runtime vs the MJX-resident
baseline, lock-step vs async.

Each configuration trains one locomotion task in its own subprocess (one per invocation, so one run fits a
10-minute command); this script watches the run's ``metrics.jsonl`` and stops it once the deterministic
evaluations have reached every goal the configuration is measured by (or at ``--max_seconds``):

* walking (every configuration): ``unilab_jax.metrics.WALKING`` on the evaluation's walking metric --
  planar tracking error <= 0.25 m/s, yaw-rate error <= 0.3 rad/s, falls <= 2% (``eval/walking``);
* on the rough-terrain configurations the rough-terrain criterion instead: the same bounds, met by an evaluation
  on terrain levels >= half the top level only (``WALKING.met_on_rough``; ``tasks/rough.py``'s evaluation runs
  on the upper half); their records add the highest mean terrain level of training and when it was reached;
* an evaluation return ``>= --target`` (Go1 configurations only: the threshold MuJoCo Playground reports,
  kept for comparison; a policy that stands still already earns a large part of it).

It appends a record to a JSON file (machine, versions, git commit, command, seed, times to each goal,
best return, throughput, the whole evaluation curve)::

    python bench/time_to_target.py --only mjx_ppo --seed 0 --max_seconds 540
    python bench/time_to_target.py --only go2_flashsac --seed 0 1 --max_seconds 270
    python bench/time_to_target.py --report          # table + ratios, writes the markdown table

A run longer than one command (a 10-minute call on the GPU machine) goes on in the next with ``--resume``: the
configuration's latest run of that seed under ``--runs_dir`` resumes from its final checkpoint (the trainer's clock
goes on from the checkpoint's, the new process's start-up counted again) for another ``--max_seconds``; its record
holds the whole run, and the report counts only the last record of each run (``logdir``).

Configurations (``CONFIGS``): ``ppo_lockstep`` / ``appo_async`` / ``fastsac_async`` / ``flashsac_async`` /
``fastsac_hold`` (Go1), ``go2_flashsac`` (Go2), ``g1_fastsac`` (G1) and, on rough terrain, ``go1_rough_ppo``,
``go1_rough_fastsac``, ``go2_rough_flashsac``, ``g1_rough_fastsac`` run the heterogeneous runtime (CPU
MuJoCo workers, ``--num_workers x --envs_per_worker``, learner on the accelerator); ``mjx_ppo`` /
``mjx_fastsac`` the GPU-resident MJX loop (``unilab_jax/training/mjx.py``) on Go1. Every run evaluates
``--eval_envs`` episodes (the configuration's, else 32) with the deterministic policy, with the same task,
reward and episode length; with 64 episodes the falls bound allows one fall, with 32 none.

Clocks: time to target is the ``eval/wall_s`` of the first evaluation reaching the target: seconds
from the training process's start (imports, XLA compilation, worker start-up included) to the moment
the evaluated weights existed. Each run compiles from an empty compilation cache of its own
(``--compilation_cache=cold``, the default; a directory instead measures warm starts), recorded as
``compilation_cache``. The runtime evaluates in a background thread; the MJX loop evaluates
in between training calls, so for it the record also holds ``train_time_to_target_s`` (the same clock
minus the time spent evaluating), and the report compares with both.

``--report`` groups records by configuration (mean over seeds), picks the heterogeneous configuration
(``--het_best``, default: the fastest to target) and the MJX one (``--mjx``, default: the fastest),
and prints the speed-ups in time to target and in env steps/s: heterogeneous vs MJX (goal >= 3x) and
``appo_async`` vs ``ppo_lockstep`` (goal >= 1.5x). A run that did not reach the target counts at its
budget, so a ratio against it is a bound (printed with >= or <=).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import glob
import hashlib
import json
import math
import os
import platform
import re
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Any

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
if REPO not in sys.path:  # bench.machine, when run as a script
    sys.path.insert(0, REPO)

from bench.machine import cpu_model  # noqa: E402
from bench.terrain_curves import windowed  # noqa: E402
from unilab_jax.metrics import WALKING  # noqa: E402

DEFAULT_OUT = os.path.join(HERE, "results", "time_to_target.json")
DEFAULT_MD = os.path.join(HERE, "results", "time_to_target.md")

# name -> kind, script, extra flags. Heterogeneous runs get --num_workers and --envs_per_worker (the config's
# "envs_per_worker", 128 if it names none, unless given on the command line): the off-policy recipes use 64
# envs per worker, as in FastTD3/FastSAC's ~1024 parallel envs. The off-policy "_async" configurations run the
# workers free (as when they were first measured); "fastsac_hold" holds the recipe's update-to-data ratio (--utd_mode's
# default). The MJX runs step the scripts' default number of envs (8192 for PPO, 1024 for FastSAC).
# "return_target": whether --target (an evaluation return on Go1's reward scale) is a goal besides walking.
# The MJX baselines evaluate as many episodes as the off-policy runs they are compared with (64): the walking
# criterion's falls bound (2%) allows one fall in 64 episodes and none in 32 (the a3435e9 MJX run had 32).
# Off-policy runs: 13 workers, which the CLI's --pin_cpus=auto keeps off 3 cores for the learner process's threads
# (docs/perf/learner_scaling.md section 8: 55-58 learner calls/s against 30-32 with 15 workers on every core).
_OFFPOLICY = {"kind": "heterogeneous", "sync": "async", "eval_every": 1_000_000, "envs_per_worker": 64, "eval_envs": 64,
              "num_workers": 13}
CONFIGS: dict[str, dict[str, Any]] = {
    "ppo_lockstep": {"kind": "heterogeneous", "sync": "lockstep", "script": "experiments/ppo_go1.py",
                     "eval_every": 2_000_000, "return_target": True},
    "appo_async": {"kind": "heterogeneous", "sync": "async", "script": "experiments/appo_go1.py",
                   "eval_every": 2_000_000, "return_target": True},
    "fastsac_async": {**_OFFPOLICY, "script": "experiments/fastsac_go1.py", "return_target": True,
                      "flags": ["--utd_mode=free"]},
    "flashsac_async": {**_OFFPOLICY, "script": "experiments/flashsac_go1.py", "return_target": True,
                       "flags": ["--utd_mode=free"]},
    "fastsac_hold": {**_OFFPOLICY, "script": "experiments/fastsac_go1.py", "return_target": True},
    "go2_flashsac": {**_OFFPOLICY, "script": "experiments/flashsac_go2.py", "return_target": False,
                     "flags": ["--utd_mode=free"]},
    "g1_fastsac": {**_OFFPOLICY, "script": "experiments/fastsac_g1.py", "return_target": False,
                   "flags": ["--utd_mode=free"]},
    # rough terrain (docs/TERRAIN.md): walking is the rough-terrain criterion, judged on the evaluation's upper-half
    # terrain levels (``metrics.WALKING.met_on_rough``); the records also hold the mean terrain level's maximum
    # (records add "robot", "algo" and "time_to_walking_rough_s": issue 33's terrain.json)
    "go1_rough_ppo": {"kind": "heterogeneous", "sync": "lockstep", "script": "experiments/ppo_go1_rough.py",
                      "eval_every": 4_000_000, "eval_envs": 64, "return_target": False, "rough": ("go1", "ppo")},
    "go1_rough_fastsac": {**_OFFPOLICY, "script": "experiments/fastsac_go1_rough.py", "return_target": False,
                          "rough": ("go1", "fastsac"), "flags": ["--utd_mode=free"]},
    "go2_rough_flashsac": {**_OFFPOLICY, "script": "experiments/flashsac_go2_rough.py", "return_target": False,
                           "rough": ("go2", "flashsac"), "flags": ["--utd_mode=free"]},
    "g1_rough_fastsac": {**_OFFPOLICY, "script": "experiments/fastsac_g1_rough.py", "return_target": False,
                         "rough": ("g1", "fastsac"), "flags": ["--utd_mode=free"]},
    # the MJX baseline on rough ground (tasks/mjx_rough.py): the Go1 MJX scripts on go1_joystick_rough
    "mjx_go1_rough_ppo": {"kind": "mjx", "sync": "lockstep", "script": "experiments/ppo_go1_mjx.py",
                          "eval_every": 10_000_000, "eval_envs": _OFFPOLICY["eval_envs"], "return_target": False,
                          "rough": ("go1", "ppo"), "flags": ["--task=go1_joystick_rough"]},
    "mjx_go1_rough_fastsac": {"kind": "mjx", "sync": "lockstep", "script": "experiments/fastsac_go1_mjx.py",
                              "eval_every": 2_000_000, "eval_envs": _OFFPOLICY["eval_envs"], "return_target": False,
                              "rough": ("go1", "fastsac"), "flags": ["--task=go1_joystick_rough"]},
    "mjx_ppo": {"kind": "mjx", "sync": "lockstep", "script": "experiments/ppo_go1_mjx.py", "eval_every": 10_000_000,
                "eval_envs": _OFFPOLICY["eval_envs"], "return_target": True},
    "mjx_fastsac": {"kind": "mjx", "sync": "lockstep", "script": "experiments/fastsac_go1_mjx.py",
                    "eval_every": 2_000_000, "eval_envs": _OFFPOLICY["eval_envs"], "return_target": True},
}
SOURCES = ("tasks/go1_joystick.py", "tasks/go1_math.py", "tasks/model_edits.py", "tasks/floating_base.py",
           "tasks/mjx_go1.py", "tasks/walking.py", "tasks/go2_joystick.py", "tasks/g1_walk.py",
           "tasks/physics.py", "unilab_jax/training/trainer.py", "unilab_jax/metrics.py",
           "unilab_jax/training/mjx.py", "unilab_jax/algos/ppo/ppo.py", "unilab_jax/algos/ppo/learner_jax.py",
           "unilab_jax/algos/offpolicy/fastsac.py", "unilab_jax/algos/offpolicy/learner_jax.py",
           "unilab_jax/runtime/pool.py", "unilab_jax/runtime/spawn.py", "unilab_jax/runtime/worker.py")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="*", default=[], help=f"configurations to run, of {sorted(CONFIGS)}")
    ap.add_argument("--seed", type=int, nargs="*", default=[0], help="seeds (each a separate run)")
    ap.add_argument("--target", type=float, default=25.0, help="evaluation return to reach (Go1 configurations)")
    ap.add_argument("--max_seconds", type=float, default=540.0, help="budget per run, from its launch")
    ap.add_argument("--stop_grace", type=float, default=30.0,
                    help="seconds between the SIGTERM that stops a run and a SIGKILL (a run with --keep_replay "
                         "writes its replay rings, GBs, in them)")
    ap.add_argument("--num_workers", type=int, default=None,
                    help="workers for heterogeneous runs (default: the config's, else 15)")
    ap.add_argument("--envs_per_worker", type=int, default=None,
                    help="envs per worker for heterogeneous runs (default: the config's, else 128)")
    ap.add_argument("--eval_envs", type=int, default=0, help="episodes per evaluation (0: the config's, else 32)")
    ap.add_argument("--eval_every", type=int, default=0, help="env steps between evaluations (0: the config's)")
    ap.add_argument("--extra", action="append", default=[], help="one more flag for the experiment script")
    ap.add_argument("--no_stop_at_target", action="store_true", help="train until the budget even after the goals")
    ap.add_argument("--runs_dir", default="/tmp/time_to_target_runs", help="where the runs' logdirs go")
    ap.add_argument("--compilation_cache", default="cold", help="cold: each run compiles everything (an empty JAX "
                    "compilation cache of its own, removed after it); a directory: the runs share that cache (a "
                    "warm start once one run filled it)")
    ap.add_argument("--resume", action="store_true", help="continue each configuration's latest run of the seed "
                    "under --runs_dir (from its checkpoint, its clock going on) for another --max_seconds")
    ap.add_argument("--metrics_dir", default=None, help="copy each run's metrics.jsonl here (<config>_s<seed>_<date>)")
    ap.add_argument("--commit", default=None, help="git commit to record (default: detected; the GPU machine's copy "
                    "has no .git)")
    ap.add_argument("--out", default=DEFAULT_OUT, help="JSON file the records are appended to")
    ap.add_argument("--report", action="store_true", help="print the table from --out instead of running")
    ap.add_argument("--md", default=DEFAULT_MD, help="markdown table written by --report")
    ap.add_argument("--het_best", default=None, help="heterogeneous configuration for the ratio (default: fastest)")
    ap.add_argument("--mjx", default=None, help="MJX configuration for the ratio (default: fastest)")
    args = ap.parse_args(argv)
    unknown = sorted(set(args.only) - set(CONFIGS))
    if unknown:
        ap.error(f"unknown configurations {unknown}; choose from {sorted(CONFIGS)}")
    if not args.report and not args.only:
        ap.error("give --only CONFIG [...] to run, or --report")
    if args.resume and any(CONFIGS[n]["kind"] != "heterogeneous" for n in args.only):
        ap.error("--resume continues runs of the heterogeneous runtime only (the MJX loop keeps no checkpoint)")
    return args


# --------------------------------------------------------------------------------------------------
# Machine and provenance
# --------------------------------------------------------------------------------------------------
def _cmd(args: list[str]) -> str | None:
    try:
        out = subprocess.run(args, capture_output=True, text=True, timeout=30, cwd=REPO)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def git_commit() -> str | None:
    """HEAD's commit, from git or, where git is absent (the GPU machine's copy), from ``.git`` itself."""
    commit = _cmd(["git", "rev-parse", "HEAD"])
    if commit:
        dirty = _cmd(["git", "status", "--porcelain", "--untracked-files=no"])
        return commit + ("+dirty" if dirty else "")
    try:
        head = open(os.path.join(REPO, ".git", "HEAD")).read().strip()
        if head.startswith("ref: "):
            return open(os.path.join(REPO, ".git", head[5:])).read().strip()
        return head
    except OSError:
        return None


def source_digest() -> str:
    """sha256 over the files that define the compared systems (provenance where git is unavailable)."""
    h = hashlib.sha256()
    for rel in SOURCES:
        path = os.path.join(REPO, rel)
        h.update(rel.encode())
        if os.path.exists(path):
            h.update(open(path, "rb").read())
    return h.hexdigest()[:16]


def machine_info() -> dict[str, Any]:
    """Host, CPU, GPU (``nvidia-smi``) and versions; jax is imported but not initialised, so this process
    takes no GPU memory from the runs."""
    cpu = cpu_model()
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for mod in ("numpy", "jax", "jaxlib", "mujoco", "optax"):
        try:
            versions[mod] = __import__(mod).__version__
        except ImportError:
            versions[mod] = None
    gpus = _cmd(["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"])
    return {"hostname": socket.gethostname(), "cpu_model": cpu, "cpu_count": os.cpu_count(),
            "cpus_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
            "gpus": gpus.splitlines() if gpus else [], "platform": platform.platform(), "versions": versions,
            "loadavg_at_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}


# --------------------------------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------------------------------
class MetricsReader:
    """Reads the rows appended to a ``metrics.jsonl`` since the last call (a partial last line waits)."""

    def __init__(self, path: str):
        self.path, self._offset, self._buf = path, 0, ""

    def new_rows(self) -> list[dict[str, Any]]:
        if not os.path.exists(self.path):
            return []
        with open(self.path) as f:
            f.seek(self._offset)
            chunk = f.read()
            self._offset = f.tell()
        self._buf += chunk
        *lines, self._buf = self._buf.split("\n")
        return [json.loads(line) for line in lines if line.strip()]


def is_walking(row: dict[str, Any], rough: bool = False) -> bool:
    """Whether an evaluation row meets the walking criterion (``metrics.WALKING``, recomputed from the row's
    numbers so that rows logged before ``eval/walking`` existed are judged alike); ``rough``: the rough-terrain
    criterion (``WALKING.met_on_rough``: met on an evaluation of terrain levels >= half the top level only)."""
    return WALKING.met_on_rough(row, prefix="eval/") if rough else WALKING.met(row, prefix="eval/")


def goals_reached(rows: list[dict[str, Any]], target: float | None, rough: bool = False) -> bool:
    """Whether the evaluation rows so far reached every goal: walking, and the return ``target`` unless None."""
    evals = [r for r in rows if "eval/return" in r]
    walked = any(is_walking(r, rough) for r in evals)
    return walked and (target is None or any(r["eval/return"] >= target for r in evals))


def terrain_levels(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The highest mean terrain level of the training rows (``episode/terrain_level`` averaged over the trailing
    episode-long window of ``terrain_curves.windowed``), its wall time and step, the grid's top level (from the level
    histogram ``episode/terrain_level_<k>``) and the highest mean as a fraction of it (issue 33's goal: >= 0.7)."""
    logged = [r for r in rows if "episode/terrain_level" in r and "time/wall_s" in r]
    smooth = windowed(sorted(logged, key=lambda r: r["time/wall_s"]))
    if not smooth:
        return {"max_terrain_level": None, "max_terrain_level_wall_s": None, "max_terrain_level_step": None,
                "terrain_level_top": None, "max_terrain_level_fraction": None}
    best, level = max(smooth, key=lambda rm: rm[1])
    prefix = "episode/terrain_level_"
    top = max((int(k[len(prefix):]) for k in best if k.startswith(prefix) and k[len(prefix):].isdigit()), default=None)
    return {"max_terrain_level": level, "max_terrain_level_wall_s": best["time/wall_s"],
            "max_terrain_level_step": best["step"], "terrain_level_top": top,
            "max_terrain_level_fraction": level / top if top else None}


def summarize(rows: list[dict[str, Any]], target: float | None, rough: bool = False) -> dict[str, Any]:
    """Times to the return ``target`` (None: not a goal of this configuration) and to walking (``rough``: by the
    rough-terrain criterion, with the highest mean terrain level), best return and throughput from a run's
    metrics rows."""
    evals = sorted((r for r in rows if "eval/return" in r), key=lambda r: r["eval/wall_s"])
    train = [r for r in rows if "perf/env_steps_per_s" in r and "time/wall_s" in r]
    out: dict[str, Any] = {"reached": False, "time_to_target_s": None, "train_time_to_target_s": None,
                           "env_steps_at_target": None, "return_at_target": None}
    hit = next((r for r in evals if r["eval/return"] >= target), None) if target is not None else None
    if hit is not None:
        out.update(reached=True, time_to_target_s=hit["eval/wall_s"],
                   train_time_to_target_s=hit.get("eval/train_wall_s", hit["eval/wall_s"]),
                   env_steps_at_target=hit["step"], return_at_target=hit["eval/return"])
    out.update(walking_reached=False, time_to_walking_s=None, train_time_to_walking_s=None,
               env_steps_at_walking=None, walking_at=None)
    walk = next((r for r in evals if is_walking(r, rough)), None)
    if walk is not None:
        out.update(walking_reached=True, time_to_walking_s=walk["eval/wall_s"],
                   train_time_to_walking_s=walk.get("eval/train_wall_s", walk["eval/wall_s"]),
                   env_steps_at_walking=walk["step"],
                   walking_at={k: walk[f"eval/{k}"] for k in ("return", *WALKING.KEYS)})
    if evals:
        best = max(evals, key=lambda r: r["eval/return"])
        out.update(best_return=best["eval/return"], best_return_wall_s=best["eval/wall_s"],
                   best_return_step=best["step"])
    else:
        out.update(best_return=None, best_return_wall_s=None, best_return_step=None)
    if len(train) >= 2:
        first, last = train[0], train[-1]
        out["env_steps_per_s_mean"] = (last["step"] - first["step"]) / max(last["time/wall_s"] - first["time/wall_s"],
                                                                           1e-9)
        out["env_steps_per_s_median"] = statistics.median(r["perf/env_steps_per_s"] for r in train[1:])
    else:
        out["env_steps_per_s_mean"] = out["env_steps_per_s_median"] = None
    if rough:
        out.update(terrain_levels(rows))
    out["first_train_row_wall_s"] = train[0]["time/wall_s"] if train else None
    out["final_env_steps"] = max((r["step"] for r in rows), default=0)
    # [step, wall s, train wall s, return, tracking error, yaw-rate error, fall rate] per evaluation
    out["evals"] = [[r["step"], round(r["eval/wall_s"], 2), round(r.get("eval/train_wall_s", r["eval/wall_s"]), 2),
                     round(r["eval/return"], 3), *(round(r.get(f"eval/{k}", math.nan), 4) for k in WALKING.KEYS)]
                    for r in evals]
    return out


# --------------------------------------------------------------------------------------------------
# Running one configuration
# --------------------------------------------------------------------------------------------------
def command(name: str, cfg: dict[str, Any], seed: int, logdir: str, args: argparse.Namespace) -> list[str]:
    cmd = [sys.executable, os.path.join(REPO, cfg["script"]), f"--seed={seed}", f"--logdir={logdir}",
           f"--eval_every={args.eval_every or cfg['eval_every']}",
           f"--eval_envs={args.eval_envs or cfg.get('eval_envs', 32)}",
           "--total_steps=10000000000"]
    if cfg["kind"] == "heterogeneous":
        envs = args.envs_per_worker or cfg.get("envs_per_worker", 128)
        cmd += [f"--num_workers={args.num_workers or cfg.get('num_workers', 15)}", f"--envs_per_worker={envs}"]
    else:
        cmd += [f"--max_seconds={args.max_seconds}"]
    return cmd + list(cfg.get("flags", [])) + list(args.extra)


def _stop(proc: subprocess.Popen, grace: float = 30.0) -> None:
    """SIGTERM to the run's process group (the trainers shut down in order), SIGKILL after ``grace`` s."""
    for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, 10.0)):
        if proc.poll() is not None:
            return
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue


def run_one(name: str, seed: int, args: argparse.Namespace, cfg: dict[str, Any] | None = None,
            poll_s: float = 1.0) -> dict[str, Any]:
    """Runs configuration ``name`` once and returns its record (not yet saved)."""
    cfg = cfg or CONFIGS[name]
    target = args.target if cfg["return_target"] else None
    rough = bool(cfg.get("rough"))
    stamp = datetime.datetime.now().strftime("%Y%m%d_%H%M%S")
    logdir = os.path.join(args.runs_dir, f"{name}_s{seed}_{stamp}")
    if args.resume:
        logdir = latest_run(args.runs_dir, name, seed)
        stamp = "_".join(os.path.basename(logdir).rsplit("_", 2)[1:])
    os.makedirs(logdir, exist_ok=True)
    cmd = command(name, cfg, seed, logdir, args) + (["--resume"] if args.resume else [])
    cache = (tempfile.mkdtemp(prefix="xla_cache_") if args.compilation_cache == "cold"
             else os.path.abspath(args.compilation_cache))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (REPO, os.environ.get("PYTHONPATH")) if p),
           "PYTHONUNBUFFERED": "1", "JAX_COMPILATION_CACHE_DIR": cache}
    reader = MetricsReader(os.path.join(logdir, "metrics.jsonl"))
    rows: list[dict[str, Any]] = []
    print(f"[{name} seed {seed}] {' '.join(cmd)}", flush=True)
    # MJX runs stop themselves at the budget (between jitted calls); the margin only catches a hung one.
    limit = args.max_seconds + (30.0 if cfg["kind"] == "mjx" else 0.0)
    t_launch = time.time()
    with open(os.path.join(logdir, "stdout.log"), "w") as log:
        proc = subprocess.Popen(cmd, cwd=REPO, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        stopped_by = "exit"
        try:
            while proc.poll() is None:
                time.sleep(poll_s)
                new = reader.new_rows()
                rows += new
                for r in new:
                    if "eval/return" in r:
                        walk = " ".join(f"{k} {r.get(f'eval/{k}', math.nan):.3f}" for k in WALKING.KEYS)
                        print(f"[{name} seed {seed}] eval {r['eval/return']:.2f} ({walk}"
                              f"{', walking' if is_walking(r, rough) else ''}) at {r['step']:,} steps, "
                              f"{r['eval/wall_s']:.0f} s", flush=True)
                if not args.no_stop_at_target and goals_reached(rows, target, rough):
                    stopped_by = "target"
                    break
                if time.time() - t_launch > limit:
                    stopped_by = "max_seconds"
                    break
        finally:
            _stop(proc, args.stop_grace)
            if args.compilation_cache == "cold":
                shutil.rmtree(cache, ignore_errors=True)
    rows += reader.new_rows()
    record = {"config": name, "kind": cfg["kind"], "sync": cfg["sync"], "seed": seed, "target": target,
              "walking_criterion": {**dataclasses.asdict(WALKING), **({"rough": True} if rough else {})},
              "max_seconds": args.max_seconds, "command": cmd[1:], "stopped_by": stopped_by,
              "returncode": proc.returncode, "bench_wall_s": time.time() - t_launch, "logdir": logdir,
              "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              **summarize(rows, target, rough)}
    if args.resume:  # the whole run's clock: its budget is where this segment stopped it
        clock = max((r["time/wall_s"] for r in rows if "time/wall_s" in r), default=args.max_seconds)
        record.update(resumed=True, segment_max_seconds=args.max_seconds, max_seconds=round(clock, 1))
    if rough:  # issue 33's record: robot, algo, seed, time to the rough-terrain criterion, the terrain level's maximum
        robot, algo = cfg["rough"]
        record.update(robot=robot, algo=algo, time_to_walking_rough_s=record["time_to_walking_s"])
    if args.metrics_dir and os.path.exists(reader.path):
        os.makedirs(args.metrics_dir, exist_ok=True)
        record["metrics_copy"] = os.path.join(args.metrics_dir, f"{name}_s{seed}_{stamp}.jsonl")
        shutil.copyfile(reader.path, record["metrics_copy"])
    record["compilation_cache"] = "cold" if args.compilation_cache == "cold" else cache
    record["startup"] = startup(open(os.path.join(logdir, "stdout.log"), errors="replace").read())
    summary_path = os.path.join(logdir, "summary.json")
    if os.path.exists(summary_path):
        record["run_summary"] = json.load(open(summary_path))
    if proc.returncode not in (0, None):  # a crash, or a run stopped at the budget that failed to shut down cleanly
        record["stdout_tail"] = open(os.path.join(logdir, "stdout.log")).read()[-3000:]
    return record


# The trainer's start-up milestones (``unilab_jax.training.trainer``'s log lines, seconds from the process start).
STARTUP_LINES = {"learner_state_s": r"learner state ready ([0-9.]+) s after the start",
                 "workers_started_s": r"workers started ([0-9.]+) s after the start",
                 "update_compile_s": r"update compiled ahead of the first call in ([0-9.]+) s",
                 "update_compiled_s": r"update compiled ahead of the first call in [0-9.]+ s, ([0-9.]+) s after"}


def startup(log_text: str) -> dict[str, float]:
    """The start-up milestones a run's log names (the first of each; absent ones left out)."""
    found = {}
    for key, pattern in STARTUP_LINES.items():
        m = re.search(pattern, log_text)
        if m:
            found[key] = float(m.group(1))
    return found


def latest_run(runs_dir: str, name: str, seed: int) -> str:
    """The newest logdir of configuration ``name`` and ``seed`` under ``runs_dir`` that holds a checkpoint."""
    runs = sorted(d for d in glob.glob(os.path.join(runs_dir, f"{name}_s{seed}_*_*"))
                  if os.path.isdir(os.path.join(d, "checkpoints")))
    if not runs:
        print(f"error: --resume: no run of {name} seed {seed} with a checkpoint under {runs_dir}", file=sys.stderr)
        sys.exit(2)
    return runs[-1]


def final_records(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The records that count: of the records of one run (``logdir``: its segments, ``--resume``) only the last."""
    last = {r.get("logdir"): i for i, r in enumerate(records)}
    return [r for i, r in enumerate(records) if r.get("logdir") is None or last[r["logdir"]] == i]


def append(path: str, record: dict[str, Any]) -> None:
    data = json.load(open(path)) if os.path.exists(path) else {"records": []}
    data["records"].append(record)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(data, f, indent=1)
    os.replace(tmp, path)


# --------------------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------------------
def group_name(record: dict[str, Any], records: list[dict[str, Any]]) -> str:
    """The record's configuration, plus ``@ <commit>`` when that configuration has records of several commits."""
    commits = {r.get("git_commit") for r in records if r["config"] == record["config"]}
    if len(commits) < 2:
        return record["config"]
    return f"{record['config']} @ {(record.get('git_commit') or 'unknown')[:7]}"


GOALS = {  # goal -> (record keys: reached, time, time without MJX evaluations, env steps at the goal)
    "walking": ("walking_reached", "time_to_walking_s", "train_time_to_walking_s", "env_steps_at_walking"),
    "return": ("reached", "time_to_target_s", "train_time_to_target_s", "env_steps_at_target"),
}


def _goal_stats(rs: list[dict[str, Any]], goal: str) -> dict[str, Any] | None:
    """Mean time to ``goal`` over the runs measured by it (None if none was): a run that missed counts at
    its budget, and the mean is then a lower bound. Records older than the walking criterion are judged
    again from their evaluation curves where those hold the walking numbers."""
    reached_key, time_key, train_key, steps_key = GOALS[goal]
    rs = [_with_walking(r) for r in rs] if goal == "walking" else [r for r in rs if r.get("target") is not None]
    rs = [r for r in rs if r.get(reached_key) is not None]
    if not rs:
        return None
    times = [r[time_key] if r[reached_key] else r["max_seconds"] for r in rs]
    train = [r[train_key] if r[reached_key] else r["max_seconds"] for r in rs]
    steps = [r[steps_key] for r in rs if r[reached_key]]
    return {"runs": len(rs), "reached": sum(bool(r[reached_key]) for r in rs), "time_s": statistics.mean(times),
            "per_seed_s": times, "train_time_s": statistics.mean(train),
            "lower_bound": not all(r[reached_key] for r in rs), "env_steps": statistics.mean(steps) if steps else None}


def _with_walking(record: dict[str, Any]) -> dict[str, Any]:
    """``record`` with its walking fields, recomputed from its evaluation curve when it predates them and the
    curve holds the walking numbers ([step, wall, train wall, return, tracking, yaw rate, falls])."""
    if "walking_reached" in record or not record.get("evals") or len(record["evals"][0]) < 7:
        return record
    rows = [{"step": e[0], "eval/wall_s": e[1], "eval/train_wall_s": e[2], "eval/return": e[3],
             **{f"eval/{k}": v for k, v in zip(WALKING.KEYS, e[4:7])}} for e in record["evals"]]
    summary = summarize(rows, None)
    return {**record, **{k: summary[k] for k in GOALS["walking"]}}


def aggregate(records: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per configuration: seeds, time to each goal (``_goal_stats``; None where not measured), mean env
    steps/s, best return. A configuration measured at several git commits (the code changed between runs)
    gets one group per commit, named ``config @ commit``."""
    out: dict[str, dict[str, Any]] = {}
    records = final_records(records)
    names = [group_name(r, records) for r in records]
    for name in sorted(set(names)):
        rs = [r for r, n in zip(records, names) if n == name]
        rates = [r["env_steps_per_s_median"] for r in rs if r.get("env_steps_per_s_median")]
        out[name] = {"kind": rs[0]["kind"], "sync": rs[0]["sync"], "seeds": [r["seed"] for r in rs], "runs": len(rs),
                     **{goal: _goal_stats(rs, goal) for goal in GOALS},
                     "env_steps_per_s": statistics.mean(rates) if rates else None,
                     "best_return": max((r["best_return"] for r in rs if r.get("best_return") is not None),
                                        default=None)}
    return out


def _pick(agg: dict[str, dict[str, Any]], kind: str, goal: str, name: str | None) -> str | None:
    if name is not None:
        if name not in agg:
            raise SystemExit(f"no records for {name!r}; have {sorted(agg)}")
        return name if agg[name][goal] else None
    names = [n for n, a in agg.items() if a["kind"] == kind and a[goal]]
    return min(names, key=lambda n: (agg[n][goal]["lower_bound"], agg[n][goal]["time_s"]), default=None)


def _ratio(slow: dict[str, Any], fast: dict[str, Any], key: str = "time_s") -> tuple[float, str]:
    """(slow / fast, relation) for one goal's stats: a missed target makes the ratio a bound."""
    r = slow[key] / fast[key]
    if fast["lower_bound"] and slow["lower_bound"]:
        return r, "?"
    if slow["lower_bound"]:
        return r, ">="
    if fast["lower_bound"]:
        return r, "<="
    return r, "="


RELATION = {"=": "", ">=": "at least ", "<=": "at most ", "?": "(neither reached the target; budget ratio) "}
GOAL_NAMES = {"walking": "walking", "return": "return {target:g}"}


def _cells(stats: dict[str, Any] | None) -> list[str]:
    """Table cells of one goal: seeds (reached), mean time, per seed, mean without MJX evaluations, env steps."""
    if stats is None:
        return ["-"] * 5
    bound = ">= " if stats["lower_bound"] else ""
    steps = f"{stats['env_steps'] / 1e6:.1f}M" if stats["env_steps"] else "-"
    return [f"{stats['runs']} ({stats['reached']})", f"{bound}{stats['time_s']:.0f}",
            ", ".join(f"{t:.0f}" for t in stats["per_seed_s"]), f"{bound}{stats['train_time_s']:.0f}", steps]


def report(records: list[dict[str, Any]], het_best: str | None = None, mjx: str | None = None,
           target: float | None = None) -> tuple[str, dict[str, Any]]:
    """(markdown, ratios) for the records."""
    agg = aggregate(records)
    target = target if target is not None else next((r["target"] for r in records if r.get("target")), 25.0)
    lines = ["| configuration | kind | walking: seeds (reached) | time to walking (s), mean | per seed (s) | "
             "same, MJX evaluations excluded (s) | env steps at walking | "
             f"return {target:g}: seeds (reached) | time to {target:g} (s), mean | per seed (s) | "
             "same, MJX evaluations excluded (s) | env steps at target | env steps/s | best return |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, a in agg.items():
        rate = f"{a['env_steps_per_s']:,.0f}" if a["env_steps_per_s"] else "-"
        best = f"{a['best_return']:.1f}" if a["best_return"] is not None else "-"
        lines.append(f"| {name} | {a['kind']} | " + " | ".join(_cells(a["walking"]) + _cells(a["return"]))
                     + f" | {rate} | {best} |")
    lines.append("")
    ratios: dict[str, Any] = {}
    for goal in GOALS:
        het, base = _pick(agg, "heterogeneous", goal, het_best), _pick(agg, "mjx", goal, mjx)
        if not (het and base):
            continue
        r, rel = _ratio(agg[base][goal], agg[het][goal])
        r_train, rel_train = _ratio(agg[base][goal], agg[het][goal], "train_time_s")
        h = {"heterogeneous": het, "mjx": base, "speedup": r, "relation": rel, "speedup_mjx_eval_excluded": r_train,
             "relation_eval_excluded": rel_train, "goal": 3.0, "met": rel in ("=", ">=") and r >= 3.0}
        if agg[het]["env_steps_per_s"] and agg[base]["env_steps_per_s"]:
            h["throughput_ratio"] = agg[het]["env_steps_per_s"] / agg[base]["env_steps_per_s"]
        ratios[f"heterogeneous_vs_mjx_{goal}"] = h
        tp = f"; env steps/s ratio {h['throughput_ratio']:.2f}x" if "throughput_ratio" in h else ""
        lines.append(f"Heterogeneous ({het}) vs MJX ({base}): time to {GOAL_NAMES[goal].format(target=target)} "
                     f"speed-up {RELATION[rel]}{r:.2f}x (MJX evaluation time excluded: {r_train:.2f}x){tp}; "
                     f"goal >= 3x: {'met' if h['met'] else 'not met'}.")
    if all(n in agg and agg[n]["return"] for n in ("ppo_lockstep", "appo_async")):
        r, rel = _ratio(agg["ppo_lockstep"]["return"], agg["appo_async"]["return"])
        a = {"speedup": r, "relation": rel, "goal": 1.5, "met": rel in ("=", ">=") and r >= 1.5}
        if agg["ppo_lockstep"]["env_steps_per_s"] and agg["appo_async"]["env_steps_per_s"]:
            a["throughput_ratio"] = agg["appo_async"]["env_steps_per_s"] / agg["ppo_lockstep"]["env_steps_per_s"]
        ratios["async_vs_lockstep"] = a
        tp = f"; env steps/s ratio {a['throughput_ratio']:.2f}x" if "throughput_ratio" in a else ""
        lines.append(f"Asynchronous (appo_async) vs lock-step (ppo_lockstep): time to {target:g} "
                     f"speed-up {RELATION[rel]}{r:.2f}x{tp}; goal >= 1.5x: {'met' if a['met'] else 'not met'}.")
    machines = sorted({f"{r['machine']['gpus'][0] if r['machine'].get('gpus') else 'no GPU'}, "
                       f"{r['machine']['cpus_usable']} CPU cores" for r in records if "machine" in r})
    if machines:
        lines.append(f"Machine: {'; '.join(machines)}.")
    return "\n".join(lines) + "\n", ratios


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.report:
        records = json.load(open(args.out))["records"]
        md, ratios = report(records, args.het_best, args.mjx, args.target)
        print(md)
        with open(args.md, "w") as f:
            f.write(md)
        print(f"wrote {args.md}")
        return
    machine, commit, digest = machine_info(), args.commit or git_commit(), source_digest()
    for name in args.only:
        for seed in args.seed:
            record = run_one(name, seed, args)
            record.update(machine=machine, git_commit=commit, source_digest=digest)
            append(args.out, record)
            status = "; ".join(
                f"{goal} {'reached at ' + format(record[keys[1]], '.0f') + ' s' if record[keys[0]] else 'not reached'}"
                for goal, keys in GOALS.items() if goal == "walking" or record["target"] is not None)
            print(f"[{name} seed {seed}] {status}; wrote {args.out}", flush=True)


if __name__ == "__main__":
    main()
