"""Where the time goes in a ``jax.profiler`` trace: device kernels ranked by total time.

    python bench/trace_summary.py DIR [--top 25] [--per_device] [--out summary.json]

DIR is a ``jax.profiler.trace(..., create_perfetto_trace=True)`` folder (e.g. one written by
``bench/learner_update.py --profile_dir``); the newest ``perfetto_trace.json.gz`` under it is read.
Device processes are those whose name contains ``/device:`` (``/host:CPU`` when no device process
exists, i.e. a CPU-only trace). Kernels are grouped into collectives (NCCL, XLA's all-reduce fusions),
matrix multiplies (cuBLAS/CUTLASS/XLA GEMM names), reductions, other fusions and copies/memsets, so the table
answers "compute-bound on GEMMs or not". Busy time is the sum of kernel durations; the span is first kernel
start to last kernel end. ``--per_device``: the same per device process, with each stream's busy time and span.
``--threads``: the Python threads of the traced process (an in-run trace, ``--profile_dir``), each named by the
outermost frame of this project it runs, with its busy time (top-level spans) and the project's functions
ranked by inclusive time, so the loop's host work can be read beside the kernels.
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import os
import re

COLLECTIVE = re.compile(r"nccl|all[-_]?reduce|all[-_]?gather|reduce[-_]?scatter|collective[-_]?permute|"
                        r"all[-_]?to[-_]?all", re.IGNORECASE)
GEMM = re.compile(r"gemm|xmma|cutlass|cublas|matmul|dot|wgmma|sm\d+_", re.IGNORECASE)
REDUCE = re.compile(r"reduce|reduction", re.IGNORECASE)
COPY = re.compile(r"memcpy|memset|copy|transpose", re.IGNORECASE)


def category(name: str) -> str:
    if COLLECTIVE.search(name):  # NCCL kernels and XLA's collective fusions (multi-device traces)
        return "collective"
    if GEMM.search(name):
        return "gemm"
    if REDUCE.search(name):
        return "reduction"
    if COPY.search(name):
        return "copy/memset"
    return "other fusion"


def load(folder: str) -> list[dict]:
    paths = sorted(glob.glob(os.path.join(folder, "**", "perfetto_trace.json.gz"), recursive=True),
                   key=os.path.getmtime)
    if not paths:
        raise SystemExit(f"no perfetto_trace.json.gz under {folder}")
    with gzip.open(paths[-1]) as f:
        data = json.load(f)
    return data["traceEvents"] if isinstance(data, dict) else data


def device_events(events: list[dict]) -> tuple[list[dict], list[str]]:
    names = {e["pid"]: e["args"]["name"] for e in events
             if e.get("ph") == "M" and e.get("name") == "process_name"}
    device = [pid for pid, n in names.items() if "/device:" in n]
    pids = set(device or [pid for pid, n in names.items() if n.startswith("/host:CPU")])
    threads = {(e["pid"], e["tid"]): e["args"]["name"] for e in events
               if e.get("ph") == "M" and e.get("name") == "thread_name"}
    chosen = [e for e in events if e.get("ph") == "X" and e["pid"] in pids]
    if device:  # device processes also carry per-stream "XLA Ops"/"XLA Modules" summary lines: keep kernels
        kernel_threads = {k for k, n in threads.items() if k[0] in pids and "Stream" in n}
        if kernel_threads:
            chosen = [e for e in chosen if (e["pid"], e["tid"]) in kernel_threads]
    for e in chosen:
        e["_process"], e["_stream"] = names[e["pid"]], threads.get((e["pid"], e["tid"]), str(e["tid"]))
    return chosen, sorted(names[p] for p in pids)


def summarise(events: list[dict], top: int) -> dict:
    total = collections.defaultdict(float)
    count = collections.Counter()
    for e in events:
        total[e["name"]] += e["dur"]
        count[e["name"]] += 1
    busy = sum(total.values())
    span = (max(e["ts"] + e["dur"] for e in events) - min(e["ts"] for e in events)) if events else 0.0
    by_cat = collections.defaultdict(float)
    for name, t in total.items():
        by_cat[category(name)] += t
    rows = [{"name": n, "category": category(n), "total_ms": t / 1e3, "calls": count[n], "share": t / busy}
            for n, t in sorted(total.items(), key=lambda kv: -kv[1])[:top]]
    return {"busy_ms": busy / 1e3, "span_ms": span / 1e3, "kernels": len(events),
            "by_category_ms": {k: v / 1e3 for k, v in sorted(by_cat.items(), key=lambda kv: -kv[1])}, "top": rows}


def python_threads(events: list[dict], top: int) -> list[dict]:
    """Per Python thread: busy time over the trace's span and the project's functions by inclusive time."""
    spans = [e for e in events if e.get("ph") == "X" and e.get("name", "").startswith("$")]
    if not spans:
        return []
    t0, t1 = min(e["ts"] for e in spans), max(e["ts"] + e["dur"] for e in spans)
    by_tid = collections.defaultdict(list)
    for e in spans:
        by_tid[e["tid"]].append(e)
    out = []
    for evs in by_tid.values():
        evs.sort(key=lambda e: (e["ts"], -e["dur"]))
        busy, end = 0.0, -1.0
        for e in evs:  # union of the spans: nested frames count once
            if e["ts"] >= end:
                busy += e["dur"]
                end = e["ts"] + e["dur"]
            elif e["ts"] + e["dur"] > end:
                busy += e["ts"] + e["dur"] - end
                end = e["ts"] + e["dur"]
        ours = [e for e in evs if re.search(r"unilab|trainer|sources|threads|evaluation|learner|pool|device_replay",
                                            e["name"])]
        total = collections.Counter()
        for e in ours:
            total[e["name"]] += e["dur"]
        label = max(ours, key=lambda e: e["dur"])["name"] if ours else evs[0]["name"]
        out.append({"thread": label, "busy_ms": busy / 1e3, "span_ms": (t1 - t0) / 1e3,
                    "top": [{"name": n, "total_ms": d / 1e3} for n, d in total.most_common(top)]})
    return sorted(out, key=lambda t: -t["busy_ms"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder")
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--per_device", action="store_true", help="also summarise each device process apart, with "
                    "each stream's busy time and span (multi-device traces: collectives run on their own streams)")
    ap.add_argument("--threads", action="store_true", help="also summarise the traced process's Python threads")
    ap.add_argument("--out", default="")
    args = ap.parse_args()
    raw = load(args.folder)
    events, processes = device_events(raw)
    s = summarise(events, args.top)
    s["processes"] = processes
    if args.per_device:
        s["per_device"] = {}
        for proc in processes:
            mine = [e for e in events if e["_process"] == proc]
            if not mine:
                continue
            d = summarise(mine, args.top)
            d["streams"] = {}
            for stream in sorted({e["_stream"] for e in mine}):
                ev = [e for e in mine if e["_stream"] == stream]
                span = max(e["ts"] + e["dur"] for e in ev) - min(e["ts"] for e in ev)
                d["streams"][stream] = {"kernels": len(ev), "busy_ms": sum(e["dur"] for e in ev) / 1e3,
                                        "span_ms": span / 1e3}
            s["per_device"][proc] = d
    print(f"processes: {', '.join(processes)}")
    print(f"{s['kernels']} kernels, busy {s['busy_ms']:.1f} ms over a span of {s['span_ms']:.1f} ms")
    for cat, ms in s["by_category_ms"].items():
        print(f"  {cat:14s} {ms:9.1f} ms  {ms / max(s['busy_ms'], 1e-9):6.1%}")
    print(f"{'total ms':>9s} {'calls':>6s} {'share':>6s}  kernel")
    for r in s["top"]:
        print(f"{r['total_ms']:9.2f} {r['calls']:6d} {r['share']:6.1%}  {r['name'][:110]}")
    for proc, d in s.get("per_device", {}).items():
        cats = ", ".join(f"{c} {ms:.1f}" for c, ms in d["by_category_ms"].items())
        print(f"{proc}: busy {d['busy_ms']:.1f} ms over {d['span_ms']:.1f} ms ({cats})")
        for stream, st in d["streams"].items():
            print(f"    {stream}: {st['kernels']} kernels, busy {st['busy_ms']:.2f} ms over {st['span_ms']:.2f} ms")
    if args.threads:
        s["python_threads"] = python_threads(raw, args.top)
        for t in s["python_threads"]:
            print(f"thread {t['thread'][:80]}: in traced frames {t['busy_ms']:.1f} of {t['span_ms']:.1f} ms")
            for r in t["top"][:12]:
                print(f"    {r['total_ms']:9.2f} ms  {r['name'][:100]}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(s, f, indent=2)


if __name__ == "__main__":
    main()
