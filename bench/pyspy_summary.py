"""Per-thread summary of a py-spy profile of one process: where each thread's samples go (issue 31: the learner
process's host time in-run, ``bench/p31_pyspy.sh``).

    python bench/pyspy_summary.py pyspy_wall.raw --taskstat stat0.txt stat1.txt --out summary.json

RAW is ``py-spy record --threads --idle --format raw`` output: one collapsed stack a line, ``frame;...;leaf COUNT``,
outermost first, the first frame ``thread (TID): NAME``. With ``--idle`` every thread is sampled at every tick, so
a thread's shares are shares of wall time (py-spy's own running/idle call, without ``--idle``, misses many waits
when it does not unwind native stacks: Python threads in ``Condition.wait`` counted as running). Per thread (most
CPU or least waiting first) the JSON holds:

- ``samples`` and ``share_of_process`` (its share of all the file's samples);
- ``states``, each sample classed by its innermost frames: ``gil_wait`` (CPython taking the GIL: ``take_gil``,
  ``PyEval_RestoreThread``, ``PyEval_AcquireThread``, ``PyGILState_Ensure`` on the stack, or ``pthread_cond_timedwait``
  as the innermost named frame: CPython 3.11-3.12 wait for the GIL with it, while C++ code waits with
  ``pthread_cond_wait``/``clockwait`` or a futex; or ``pthread_cond_wait`` called from Python or libpython: a thread
  dropping the GIL on a forced switch waits there until another takes it), ``blocked`` (in a sleeping call: futex,
  condition-variable, semaphore and Python lock waits, poll/epoll/select, sleeps, reads, joins), ``yield``
  (``sched_yield``: a spin-wait), ``cuda_driver`` (the innermost frame in libcuda: the driver running or spinning),
  ``python`` (the innermost frame a Python function) and ``native:LIB`` (running in library LIB). These need
  ``--native`` stacks; in Python-only stacks the innermost frame is the Python function that is running or made
  the C call the thread is in, so they class as ``python``, except the standard library's waits
  (``Condition.wait``, ``Event.wait``, selectors, thread joins: ``blocked``);
- ``self``: the innermost named frame's share (``fn (lib)`` for native, ``fn (file.py)`` for Python: line numbers and
  unnamed addresses dropped, but an unnamed innermost frame of another library than libc and the named frame's
  stands as ``? (lib)``: e.g. the stripped CUDA driver), ``inclusive``: the share of samples each frame is on the
  stack in (frames on every sample of the thread, its entry points, left out), ``python``: the same for Python
  frames alone;
- ``cpu_pct``, ``core``: with ``--taskstat``, the thread's CPU use between two snapshots of ``/proc/PID/task/*/stat``
  (each file: a first line with the time in seconds, then the stat lines), 100 = one core, and the core it ran on
  last. Threads py-spy does not see (XLA's and the CUDA driver's native threads) are listed from the snapshots alone,
  under ``threads_cpu`` (every thread, named by py-spy where it is a Python thread, else by its ``comm``).

The printed report lists the threads that lived through the record (the short-lived ones, e.g. checkpointing's,
are counted in one line).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from collections import Counter, defaultdict

_THREAD = re.compile(r"^thread \((0x[0-9a-fA-F]+|\d+)\)(?::\s*(.*))?$")
_FRAME = re.compile(r"^(?P<fn>.*?) \((?P<where>[^()]*)\)$")
_GIL = {"take_gil", "PyEval_RestoreThread", "PyEval_AcquireThread", "PyGILState_Ensure", "_PyEval_AcquireLock"}
_GIL_LEAF = {"pthread_cond_timedwait", "__pthread_cond_timedwait"}
_COND = {"pthread_cond_wait", "__pthread_cond_wait"}
_WAIT = {"pthread_cond_wait", "__pthread_cond_wait", "pthread_cond_clockwait", "sem_wait", "sem_timedwait",
         "sem_clockwait", "do_futex_wait", "__futex_abstimed_wait_common", "__futex_abstimed_wait_common64",
         "futex_wait", "syscall", "epoll_wait", "epoll_pwait", "poll", "__poll", "ppoll", "select", "__select",
         "pselect", "nanosleep", "__nanosleep", "clock_nanosleep", "__clock_nanosleep", "usleep", "sleep",
         "pthread_join", "read", "__read", "__libc_read", "recv", "recvfrom", "recvmsg", "accept", "accept4",
         "waitpid", "wait4", "__libc_recv", "pause", "sigtimedwait", "sigwaitinfo",
         "PyThread_acquire_lock_timed"}
_WAIT_CXX = ("Futex", "PerThreadSem", "CondVar::Wait", "condition_variable::wait", "WaitForNotification",
             "Notification::Wait")
_WAIT_PY = {"Condition.wait", "Event.wait", "Thread.join", "Thread._wait_for_tstate_lock", "_PollLikeSelector.select",
            "EpollSelector.select", "SelectSelector.select", "PollSelector.select"}
_YIELD = {"sched_yield", "__sched_yield"}


def parse_raw(lines: list[str]) -> list[tuple[str, str, tuple[str, ...], int]]:
    """(tid, thread name, frames outermost first without the thread frame, count) per collapsed stack."""
    stacks = []
    for line in lines:
        line = line.rstrip("\n")
        if not line.strip():
            continue
        stack, _, count = line.rpartition(" ")
        if not stack or not count.isdigit():
            raise ValueError(f"not a collapsed stack line: {line[:120]!r}")
        frames = stack.split(";")
        m = _THREAD.match(frames[0])
        tid, name = (m.group(1), m.group(2) or "") if m else ("?", "")
        stacks.append((tid, name, tuple(frames[1:] if m else frames), int(count)))
    return stacks


def normalize(frame: str) -> str:
    """``fn (file.py)`` for a Python frame (line dropped), ``fn (lib)`` for a native one, ``? (lib)`` unnamed."""
    m = _FRAME.match(frame)
    if not m:
        return frame
    fn, where = m.group("fn"), m.group("where")
    if re.fullmatch(r"[^:]+\.py:\d+", where):
        where = where.rsplit(":", 1)[0]
    else:
        where = re.sub(r"\.cpython-[^/]*\.so$", ".so", os.path.basename(where))
    if re.fullmatch(r"0x[0-9a-fA-F]+", fn):
        fn = "?"
    return f"{fn} ({where})"


def _fn(frame: str) -> str:
    return frame.rsplit(" (", 1)[0]


def _lib(frame: str) -> str:
    return frame.rsplit(" (", 1)[1].rstrip(")") if " (" in frame else ""


def is_python(frame: str) -> bool:
    return _lib(frame).endswith(".py")


def state(frames: tuple[str, ...]) -> str:
    """The class of one sample (normalized frames, outermost first): see the module's docstring."""
    if not frames:
        return "unknown"
    named = [f for f in reversed(frames) if _fn(f) != "?"]  # innermost first
    if any(_fn(f) in _GIL for f in named[:8]):
        return "gil_wait"
    inner = _fn(named[0]) if named else ""
    caller = named[1] if len(named) > 1 else ""
    if inner in _GIL_LEAF or (inner in _COND and (is_python(caller) or "libpython" in _lib(caller))):
        return "gil_wait"
    if (inner in _WAIT or any(s in _fn(f) for f in named[:3] for s in _WAIT_CXX)
            or (is_python(frames[-1]) and _fn(frames[-1]) in _WAIT_PY)):
        return "blocked"
    if inner in _YIELD:
        return "yield"
    leaf = frames[-1]
    if "libcuda" in _lib(leaf):
        return "cuda_driver"
    if is_python(leaf):
        return "python"
    return f"native:{_lib(leaf)}"


def self_frame(frames: tuple[str, ...]) -> str:
    """The innermost named frame; an unnamed innermost frame (``? (lib)``) stands for itself when its library is
    neither the named frame's nor libc (code of a stripped library, e.g. the CUDA driver, called from elsewhere)."""
    named = [f for f in frames if _fn(f) != "?"]
    if not frames or not named:
        return frames[-1] if frames else "?"
    leaf = frames[-1]
    if _fn(leaf) == "?" and _lib(leaf) != _lib(named[-1]) and not _lib(leaf).startswith("libc."):
        return leaf
    return named[-1]


def _top(counter: Counter, total: int, n: int) -> list[list]:
    return [[k, round(v / total, 4)] for k, v in counter.most_common(n)]


def read_taskstat(path: str) -> tuple[float, dict[str, dict]]:
    """(time, {tid: {comm, ticks, core}}) of one snapshot file."""
    with open(path) as f:
        lines = f.read().splitlines()
    t, threads = float(lines[0]), {}
    for line in lines[1:]:
        if ")" not in line:
            continue
        head, _, rest = line.rpartition(")")
        tid, _, comm = head.partition(" (")
        fields = rest.split()  # fields[0] is the state (stat field 3)
        threads[tid.strip()] = {"comm": comm, "ticks": int(fields[11]) + int(fields[12]), "core": int(fields[36])}
    return t, threads


def threads_cpu(before: str, after: str, names: dict[str, str]) -> list[dict]:
    """Every thread alive at both snapshots: CPU % (100 = one core) between them, largest first."""
    (t0, s0), (t1, s1) = read_taskstat(before), read_taskstat(after)
    hz, span = os.sysconf("SC_CLK_TCK"), max(t1 - t0, 1e-9)
    rows = [{"tid": tid, "name": names.get(tid) or s1[tid]["comm"], "comm": s1[tid]["comm"],
             "cpu_pct": round(100.0 * (s1[tid]["ticks"] - s0[tid]["ticks"]) / hz / span, 1), "core": s1[tid]["core"]}
            for tid in s1 if tid in s0]
    return sorted(rows, key=lambda r: -r["cpu_pct"])


def summarize(stacks: list[tuple[str, str, tuple[str, ...], int]], top: int = 15,
              cpu: list[dict] | None = None) -> dict:
    """The per-thread summary of parsed stacks (``parse_raw``), with ``threads_cpu`` rows if given."""
    per: dict[tuple[str, str], list[tuple[tuple[str, ...], int]]] = defaultdict(list)
    for tid, name, frames, count in stacks:
        per[(tid, name)].append((tuple(normalize(f) for f in frames), count))
    total = sum(c for *_, c in stacks) or 1
    by_tid = {r["tid"]: r for r in cpu or []}
    threads = []
    for (tid, name), samples in per.items():
        n = sum(c for _, c in samples)
        states, selfs, incl, py = Counter(), Counter(), Counter(), Counter()
        for frames, c in samples:
            states[state(frames)] += c
            selfs[self_frame(frames)] += c
            for f in set(frames):
                incl[f] += c
                if is_python(f):
                    py[f] += c
        everywhere = {f for f, c in incl.items() if c == n}
        row = {"tid": tid, "name": name, "samples": n, "share_of_process": round(n / total, 4),
               "states": dict(_top(states, n, len(states))), "self": _top(selfs, n, top),
               "inclusive": _top(Counter({f: c for f, c in incl.items() if f not in everywhere}), n, top),
               "python": _top(Counter({f: c for f, c in py.items() if f not in everywhere}), n, top)}
        if tid in by_tid:
            row.update(cpu_pct=by_tid[tid]["cpu_pct"], core=by_tid[tid]["core"])
        threads.append(row)
    def active(r: dict) -> float:
        return r["samples"] * (1 - sum(v for k, v in r["states"].items() if k in ("blocked", "gil_wait")))

    threads.sort(key=lambda r: (-r.get("cpu_pct", 0.0), -active(r)))
    out = {"samples": total, "threads": threads}
    if cpu is not None:
        out.update(process_cpu_pct=round(sum(r["cpu_pct"] for r in cpu), 1), threads_cpu=cpu)
    return out


def report(summary: dict, frames: int = 6) -> str:
    lines = [f"{summary['samples']} samples" + (f", process CPU {summary['process_cpu_pct']}% (100 = one core)"
                                                 if "process_cpu_pct" in summary else "")]
    longest = max((r["samples"] for r in summary["threads"]), default=0)
    short = [r for r in summary["threads"] if r["samples"] < longest / 2]
    for r in summary["threads"]:
        if r in short:
            continue
        cpu = f" cpu {r['cpu_pct']}% core {r['core']}" if "cpu_pct" in r else ""
        states = ", ".join(f"{k} {v:.0%}" for k, v in r["states"].items() if v >= 0.01)
        lines.append(f"{r['name'] or '?'} ({r['tid']}): {r['share_of_process']:.1%} of samples{cpu}; {states}")
        lines += [f"    self {v:6.1%}  {k}" for k, v in r["self"][:frames]]
        lines += [f"    py   {v:6.1%}  {k}" for k, v in r["python"][:frames]]
    if short:
        lines.append(f"{len(short)} short-lived threads (sampled less than half the record): "
                     f"{sum(r['share_of_process'] for r in short):.1%} of samples")
    native = [r for r in summary.get("threads_cpu", []) if r["cpu_pct"] >= 1.0
              and r["tid"] not in {t["tid"] for t in summary["threads"]}]
    if native:
        lines.append("threads py-spy does not sample (native), CPU %: "
                     + ", ".join(f"{r['name']} ({r['tid']}) {r['cpu_pct']}" for r in native))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("raw", help="py-spy record --threads --format raw output")
    ap.add_argument("--taskstat", nargs=2, metavar=("BEFORE", "AFTER"), help="/proc/PID/task/*/stat snapshots")
    ap.add_argument("--top", type=int, default=15, help="frames listed per thread and kind")
    ap.add_argument("--out", help="write the summary as JSON here")
    args = ap.parse_args(argv)
    try:
        with open(args.raw) as f:
            stacks = parse_raw(f.readlines())
        names = {tid: name for tid, name, _, _ in stacks}
        cpu = threads_cpu(*args.taskstat, names) if args.taskstat else None
    except (OSError, ValueError, IndexError) as e:
        print(f"pyspy_summary: {e}", file=sys.stderr)
        sys.exit(2)
    summary = summarize(stacks, args.top, cpu)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(summary, f, indent=1)
    print(report(summary))


if __name__ == "__main__":
    main()
