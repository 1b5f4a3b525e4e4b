"""Replay sampling throughput: shared memory only vs the disk store only vs both tiers mixed.

    python bench/replay_store.py --rows 1000000 --dir /tmp --out bench/results/replay_store_local.json

Go1-sized transitions (obs 48, critic obs 123, action 12, 16 reward terms). The same ``--rows``
transitions go into

* **memory**: a shared-memory :class:`ReplayBuffer` (2 worker regions), sampled with
  ``ReplayBuffer.sample``: what ``pool.sample`` does today, including the per-row checksum check
  (it returns every transition field, ~1.5 KB a row);
* **disk**: a :class:`ReplayStore` under ``--dir`` (16 MiB chunks), sampled with
  ``ReplayStore.sample`` (the learner's fields only, 1422 bytes a row). *warm*: every chunk file
  was just read, so the whole store is in the OS page cache. *cold*: before every timed batch the store's pages
  are dropped from this process's mappings and from the page cache (``madvise(MADV_DONTNEED)`` +
  ``posix_fadvise(POSIX_FADV_DONTNEED)``), so each batch reads from the device;
* **cached**: :class:`TieredSampler`, ``--hot_fractions`` of every minibatch from memory, the rest
  from disk (warm; and cold for the middle fraction).

Rates are transitions/s and MB/s of the learner's fields (1422 bytes a row for every mode, so
memory-only is credited only for what the learner reads): warm modes from the fastest of 8 timed
windows, cold from the median batch (see :func:`timed`, :func:`timed_cold`). Batches of ``--batches`` (4096:
FastSAC-like; 256), each timed for ``--seconds`` (cold: ``--cold_batches`` batches). Also reports
the store's write rate (append + chunk commit with fsync). Prints a table and writes JSON with
machine info (``bench/throughput.py``'s) plus the disk's filesystem and the RAM size.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from types import SimpleNamespace

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
for p in (REPO, HERE):
    if p not in sys.path:
        sys.path.insert(0, p)

import numpy as np  # noqa: E402
from machine import write_json  # noqa: E402

from unilab_jax.fields import REPLAY_FIELDS  # noqa: E402
from unilab_jax.runtime.buffers import ReplayBuffer, transition_layout  # noqa: E402
from unilab_jax.runtime.replay_store import ReplayStore, TieredSampler  # noqa: E402

GO1 = SimpleNamespace(obs_dim=48, critic_obs_dim=123, action_dim=12, reward_terms=tuple(f"t{i}" for i in range(16)))
WORKERS, BLOCK = 2, 4096


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", type=int, default=1_000_000, help="transitions in each tier")
    ap.add_argument("--batches", type=int, nargs="+", default=[4096, 256])
    ap.add_argument("--hot_fractions", type=float, nargs="+", default=[0.25, 0.5, 0.75])
    ap.add_argument("--seconds", type=float, default=3.0, help="timed window per warm measurement")
    ap.add_argument("--cold_batches", type=int, default=20, help="timed batches per cold measurement")
    ap.add_argument("--dir", default=tempfile.gettempdir(), help="where the store is written (a real disk)")
    ap.add_argument("--out", default=os.path.join(HERE, "results", "replay_store_local.json"))
    args = ap.parse_args(argv)
    if args.rows < WORKERS * BLOCK or args.seconds <= 0 or args.cold_batches <= 0:
        ap.error(f"--rows must be >= {WORKERS * BLOCK}; --seconds and --cold_batches positive")
    return args


def random_rows(fields: dict, n: int, rng: np.random.Generator, bool_rate: float = 0.01) -> dict[str, np.ndarray]:
    """``n`` random transitions of the layout ``fields`` (flags true with probability ``bool_rate``)."""
    out = {}
    for name, (shape, dt) in fields.items():
        if dt == np.bool_:
            out[name] = rng.random((n, *shape)) < bool_rate
        elif np.issubdtype(dt, np.integer):
            out[name] = rng.integers(0, 1000, (n, *shape)).astype(dt)
        else:
            out[name] = rng.standard_normal((n, *shape), dtype=np.float32)
    return out


def fill(rows: int, directory: str) -> tuple[ReplayBuffer, ReplayStore, float]:
    """The same transitions into both tiers; returns them and the store's write rate (MB/s)."""
    layout = transition_layout(GO1)
    ring = ReplayBuffer.create(layout, WORKERS, BLOCK, -(-rows // (WORKERS * BLOCK)) * BLOCK)
    store = ReplayStore(directory, {k: layout[k] for k in REPLAY_FIELDS})
    rng = np.random.default_rng(0)
    written, write_s = 0, 0.0
    while written < rows:
        block = random_rows(layout, BLOCK, rng)
        w = (written // BLOCK) % WORKERS
        _, views = ring.rows(w)
        for name, view in views.items():
            view[...] = block[name]
        ring.commit(w)
        t0 = time.perf_counter()
        store.append(block)
        write_s += time.perf_counter() - t0
        written += BLOCK
    t0 = time.perf_counter()
    store.flush()
    write_s += time.perf_counter() - t0
    return ring, store, written * store.dtype.itemsize / write_s / 1e6


def timed(sample, seconds: float, windows: int = 8) -> tuple[float, list[float]]:
    """Seconds per ``sample()`` call in the fastest of ``windows`` windows of ``seconds / windows``
    (after one untimed call). Other jobs on a small machine only ever slow a window down, so the
    fastest window is the closest to the uncontended cost (timeit's argument); every window's value
    is kept in the JSON."""
    sample()
    per_call = []
    for _ in range(windows):
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds / windows:
            sample()
            n += 1
        per_call.append((time.perf_counter() - t0) / n)
    return min(per_call), per_call


def timed_cold(sample, store: ReplayStore, batches: int) -> tuple[float, list[float]]:
    """Seconds per ``sample()`` call, the median of single calls with the store's pages evicted
    (untimed) before each: a device read can be lucky (its own cache), so not the fastest."""
    per_call = []
    for _ in range(batches):
        store.evict_page_cache()
        t0 = time.perf_counter()
        sample()
        per_call.append(time.perf_counter() - t0)
    return float(np.median(per_call)), per_call


def warm_page_cache(store: ReplayStore) -> None:
    """Reads every chunk file once, so warm measurements find the whole store in the page cache."""
    for name in os.listdir(store.directory):
        if name.startswith("chunk_"):
            with open(os.path.join(store.directory, name), "rb") as f:
                while f.read(16 << 20):
                    pass


def cached_kib() -> int:
    with open("/proc/meminfo") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("Cached:"))


def disk_info(path: str) -> dict:
    best, fs, dev = "", "", ""
    with open("/proc/mounts") as f:
        for line in f:
            device, mount, kind = line.split()[:3]
            if os.path.abspath(path).startswith(mount) and len(mount) > len(best):
                best, fs, dev = mount, kind, device
    st = os.statvfs(path)
    return {"dir": os.path.abspath(path), "mount": best, "fs": fs, "device": dev,
            "free_gb": st.f_bavail * st.f_frsize / 1e9}


def main(argv=None) -> dict:
    from throughput import machine_info

    args = parse_args(argv)
    work = tempfile.mkdtemp(prefix="unilab_replay_bench_", dir=args.dir)
    info = {**machine_info(), "disk": disk_info(work),
            "ram_gb": os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 1e9}
    ring = store = None
    results: list[dict] = []
    try:
        t0 = time.perf_counter()
        ring, store, write_mb_s = fill(args.rows, os.path.join(work, "store"))
        print(f"filled {args.rows:,} transitions per tier in {time.perf_counter() - t0:.1f} s; store: "
              f"{store.num_chunks} chunks, {store.disk_bytes / 1e9:.2f} GB, written at {write_mb_s:.0f} MB/s")
        row_bytes = store.dtype.itemsize
        rng = np.random.default_rng(1)

        def add(mode: str, batch: int, cache: str, per_call: float, samples: list[float]) -> None:
            rate = batch / per_call
            results.append({"mode": mode, "batch": batch, "page_cache": cache, "transitions_per_s": rate,
                            "mb_per_s": rate * row_bytes / 1e6, "ms_per_batch": per_call * 1e3,
                            "ms_per_batch_samples": [x * 1e3 for x in samples],
                            "loadavg_1min": os.getloadavg()[0]})
            print(f"  {mode:<22} B={batch:<5} {cache:<5} {rate:>12,.0f} transitions/s {rate * row_bytes / 1e6:>8.0f} "
                  f"MB/s {per_call * 1e3:>8.2f} ms/batch", flush=True)

        for batch in args.batches:
            warm_page_cache(store)  # (the previous batch size's cold runs dropped it)
            add("memory", batch, "-", *timed(lambda b=batch: ring.sample(b, rng), args.seconds))
            add("disk", batch, "warm", *timed(lambda b=batch: store.sample(b, rng), args.seconds))
            for h in args.hot_fractions:
                tiers = TieredSampler(ring.size, ring.sample, store, h, REPLAY_FIELDS)
                add(f"cached hot={h:g}", batch, "warm", *timed(lambda b=batch, s=tiers: s.sample(1, b, rng),
                                                                 args.seconds))
            before = cached_kib()
            store.evict_page_cache()
            evicted_mb = (before - cached_kib()) / 1024
            add("disk", batch, "cold", *timed_cold(lambda b=batch: store.sample(b, rng), store, args.cold_batches))
            h = args.hot_fractions[len(args.hot_fractions) // 2]
            tiers = TieredSampler(ring.size, ring.sample, store, h, REPLAY_FIELDS)
            add(f"cached hot={h:g}", batch, "cold",
                *timed_cold(lambda b=batch, s=tiers: s.sample(1, b, rng), store, args.cold_batches))
            results[-2]["page_cache_dropped_mb"] = evicted_mb
    finally:
        if store is not None:
            store.close()
        if ring is not None:
            ring.close()
        shutil.rmtree(work, ignore_errors=True)
    out = {"machine": info, "args": vars(args), "row_bytes": row_bytes, "store_write_mb_per_s": write_mb_s,
           "loadavg_at_end": list(os.getloadavg()), "results": results}
    write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
