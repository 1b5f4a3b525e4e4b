"""Replay ring sampling speed: ``ReplayBuffer.sample`` of the working tree vs a baseline commit's.

    python bench/replay_sample.py --baseline e348aa0 --out bench/results/replay_sample_local.json

Go1-sized transitions (obs 48, critic obs 123, action 12, 16 reward terms: 1502 bytes a row, every
transition field, which is what ``sample`` returns) in ``--workers`` rings of ``--envs`` envs each,
``--capacity`` transitions in all (FastSAC's recipe: 2,097,152 over 15 workers), every ring written
full through the worker API (``rows`` + ``commit``, so each implementation stores its own
checksums). ``--baseline REF`` loads ``unilab_jax/runtime/buffers.py`` as of git ``REF`` beside the
working tree's module and fills a second buffer with it; the two are timed in alternation, so both
see the same load on a shared machine. Each batch size in ``--batches`` (65,536 = FastSAC's
U * B = 8 * 8192; 8192) is timed for at least ``--seconds`` and ``--min_calls`` calls per
implementation. Rates are rows/s and MB/s of returned data from the median call (the fastest call
is recorded too). The working tree's ``sample`` is also timed with one gather thread (its default
is one per usable core, at most 4). Two reference rows, on one fixed draw of the same size: the
working tree's gather alone (``ReplayBuffer._gather``, what ``sample`` costs without drawing and
validating) and one ``row_checksums`` pass over the batch (what verifying the copy by the rows'
checksums, as the baseline does, would add to it).

Prints a table and writes JSON with machine info (``bench/throughput.py``'s).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
import types
from collections.abc import Callable

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
for p in (REPO, HERE):
    if p not in sys.path:
        sys.path.insert(0, p)

import numpy as np  # noqa: E402
from machine import write_json  # noqa: E402
from replay_store import GO1, random_rows  # noqa: E402

from unilab_jax.runtime import buffers  # noqa: E402

BLOCK = 4096  # distinct random rows written over and over while filling


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, default=15)
    ap.add_argument("--envs", type=int, default=64, help="envs per worker (rows per commit)")
    ap.add_argument("--capacity", type=int, default=2_097_152, help="transitions in all rings together")
    ap.add_argument("--batches", type=int, nargs="+", default=[65536, 8192])
    ap.add_argument("--baseline", default=None, help="git ref whose buffers.py is timed beside the working tree's")
    ap.add_argument("--seconds", type=float, default=4.0, help="timed seconds per implementation and batch size")
    ap.add_argument("--min_calls", type=int, default=7)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "replay_sample_local.json"))
    args = ap.parse_args(argv)
    if min(args.workers, args.envs, args.capacity, args.min_calls, *args.batches) <= 0 or args.seconds <= 0:
        ap.error("sizes, --seconds and --min_calls must be positive")
    return args


def load_baseline(ref: str) -> tuple[types.ModuleType, str]:
    """``buffers.py`` as of git ``ref``, as a module of its own; returns (module, full commit hash)."""
    commit = subprocess.check_output(["git", "-C", REPO, "rev-parse", ref], text=True).strip()
    src = subprocess.check_output(["git", "-C", REPO, "show", f"{commit}:unilab_jax/runtime/buffers.py"], text=True)
    name = f"baseline_buffers_{commit[:12]}"
    mod = types.ModuleType(name)
    mod.__file__ = f"{commit}:unilab_jax/runtime/buffers.py"
    sys.modules[name] = mod  # dataclasses look the module up while the class body runs
    exec(compile(src, mod.__file__, "exec"), mod.__dict__)
    return mod, commit


def fill(buf, rng: np.random.Generator) -> float:
    """Writes every ring full through rows() + commit(); returns the seconds it took."""
    block = random_rows(buf.fields, BLOCK, rng, bool_rate=0.02)
    m, t0 = buf.envs_per_worker, time.perf_counter()
    for w in range(buf.num_workers):
        while buf.count(w) < buf.capacity:
            start, views = buf.rows(w)
            at = (start * 7 + w * 131) % (BLOCK - m + 1)
            for name, view in views.items():
                view[...] = block[name][at : at + m]
            buf.commit(w)
    return time.perf_counter() - t0


def timed(calls: dict[str, Callable[[], object]], seconds: float, min_calls: int) -> dict[str, list[float]]:
    """Calls every function in turn until each has run ``min_calls`` times and ``seconds`` in all."""
    times: dict[str, list[float]] = {k: [] for k in calls}
    for f in calls.values():
        f()  # warm-up: first touch of the output pages, page-table walks
    while any(len(t) < min_calls or sum(t) < seconds for t in times.values()):
        for k, f in calls.items():
            t0 = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t0)
    return times


def single_thread(buf, batch: int, rng: np.random.Generator) -> None:
    threads, buf.gather_threads = buf.gather_threads, 1
    try:
        buf.sample(batch, rng)
    finally:
        buf.gather_threads = threads


def row_bytes(fields) -> int:
    return sum(int(np.prod(s, dtype=np.int64)) * np.dtype(d).itemsize for s, d in fields.values())


def main(argv=None) -> dict:
    args = parse_args(argv)
    from throughput import machine_info

    fields = buffers.transition_layout(GO1, {})
    per_worker = -(-args.capacity // args.workers)
    impls = {"working tree": buffers}
    baseline_commit = None
    if args.baseline:
        impls["baseline"], baseline_commit = load_baseline(args.baseline)
    rb = row_bytes(fields)
    result = {"machine": machine_info(), "config": vars(args) | {"row_bytes": rb, "baseline_commit": baseline_commit}}
    bufs = {}
    try:
        for label, mod in impls.items():
            bufs[label] = mod.ReplayBuffer.create(fields, args.workers, args.envs, per_worker)
        new = bufs["working tree"]
        result["config"] |= {"capacity_per_worker": new.capacity, "gather_threads": new.gather_threads}
        print(f"{args.workers} rings x {new.capacity} transitions ({rb} B a row, "
              f"{args.workers * new.capacity * rb / 2**30:.2f} GiB each buffer) on {result['machine']['cpu_model']} "
              f"({result['machine']['cpus_usable']} usable cores, load {result['machine']['loadavg_at_start']}), "
              f"{new.gather_threads} gather threads", flush=True)
        for label, b in bufs.items():
            print(f"filled {label}: {fill(b, np.random.default_rng(1)):.1f} s", flush=True)
        rows = []
        for batch in args.batches:
            rngs = {label: np.random.default_rng(batch) for label in bufs}
            calls = {label: (lambda b=b, r=rngs[label], n=batch: b.sample(n, r)) for label, b in bufs.items()}
            if new.gather_threads > 1:
                one = np.random.default_rng(batch)
                calls["working tree, 1 thread"] = lambda n=batch, r=one: single_thread(new, n, r)
            # Reference rows, on one fixed draw.
            flat = np.random.default_rng(0).integers(0, new.num_workers * new.capacity, batch)
            part = new.sample(batch, np.random.default_rng(0))

            def gather_only(flat=flat, part=part):
                new._gather(flat, part)

            calls["ref: gather only"] = gather_only
            calls["ref: checksum pass"] = lambda part=part, batch=batch: buffers.row_checksums(part, batch)
            times = timed(calls, args.seconds, args.min_calls)
            base = float(np.median(times["baseline"])) if "baseline" in times else None
            for label, t in times.items():
                med = float(np.median(t))
                rows.append({"impl": label, "batch": batch, "calls": len(t), "median_s": med, "min_s": float(min(t)),
                             "rows_per_s": batch / med, "mb_per_s": batch * rb / med / 1e6,
                             "speedup_vs_baseline": base / med if base and not label.startswith("ref") else None})
        result["results"] = rows
        result["resampled"] = {label: b.resampled for label, b in bufs.items()}
    finally:
        for b in bufs.values():
            b.close()

    print(f"\n{'implementation':24s} {'batch':>7s} {'calls':>6s} {'median ms':>10s} {'min ms':>8s} "
          f"{'rows/s':>11s} {'MB/s':>8s} {'speedup':>8s}")
    for r in rows:
        sp = f"{r['speedup_vs_baseline']:.2f}x" if r["speedup_vs_baseline"] else ""
        print(f"{r['impl']:24s} {r['batch']:7d} {r['calls']:6d} {r['median_s'] * 1e3:10.1f} {r['min_s'] * 1e3:8.1f} "
              f"{r['rows_per_s']:11,.0f} {r['mb_per_s']:8,.0f} {sp:>8s}")
    print()
    write_json(args.out, result)
    return result


if __name__ == "__main__":
    main()
