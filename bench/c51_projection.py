"""The C51 target projection on the accelerator: formulations side by side, plus the fused HLO of the slowest
kernel of the real FastSAC update.

    python bench/c51_projection.py --batch 8192 --atoms 101 --out bench/results/h100/c51_projection.json

Each variant maps target-critic logits [2, B, K], rewards [B] and discounts [B] to the projected target
[B, K] on the support ``uniform_support(-0.5, 1.5, K)`` in one ``jax.jit`` (softmax, clipped-double-Q choice,
projection), as ``fastsac.categorical_target`` does. Timings are medians of ``--repeats`` calls, each waited on.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO not in sys.path:
    sys.path.insert(0, REPO)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from unilab_jax import xp as shim  # noqa: E402
from unilab_jax.core import c51  # noqa: E402

V_MIN, V_MAX = -0.5, 1.5


def _choose(logits, atoms):
    probs = jax.nn.softmax(logits, axis=-1)
    values = jnp.sum(probs * atoms, axis=-1)
    return jnp.where((values[0] <= values[1])[:, None], probs[0], probs[1])


def library(logits, rewards, discounts, atoms):
    """``core.c51.categorical_projection``, the dense form for any support (inputs materialised before the
    [B, K, K] weight)."""
    return c51.categorical_projection(atoms, _choose(logits, atoms), rewards, discounts)


def uniform(logits, rewards, discounts, atoms):
    """``core.c51.categorical_projection_uniform``, the O(B K) form (FastSAC's ``projection="prefix"``: prefix
    sums gathered at the ends of each cell's range of sources)."""
    return c51.categorical_projection_uniform(_choose(logits, atoms), rewards, discounts, v_min=V_MIN, v_max=V_MAX)


def library_fusable(logits, rewards, discounts, atoms):
    """The same code with the shim's ``materialize`` made a no-op while tracing: XLA may fuse the softmax
    into the projection (the behaviour before ``materialize`` was added)."""
    backend = type(shim.get("jax"))
    original = backend.materialize
    backend.materialize = lambda self, tree: tree
    try:
        return library(logits, rewards, discounts, atoms)
    finally:
        backend.materialize = original


def scatter(logits, rewards, discounts, atoms):
    """Each shifted atom's mass goes to its two neighbours with ``.at[].add`` (2 B K updates)."""
    probs = _choose(logits, atoms)
    k = atoms.shape[0]
    z = jnp.clip(rewards[:, None] + discounts[:, None] * atoms[None, :], atoms[0], atoms[-1])
    lower = jnp.clip(jnp.searchsorted(atoms, z, side="right") - 1, 0, k - 2)
    a_lo, a_hi = atoms[lower], atoms[lower + 1]
    w_hi = jnp.clip((z - a_lo) / (a_hi - a_lo), 0.0, 1.0)
    rows = jnp.arange(z.shape[0])[:, None] * k
    out = jnp.zeros(z.size, jnp.float32)
    out = out.at[(rows + lower).ravel()].add((probs * (1.0 - w_hi)).ravel())
    out = out.at[(rows + lower + 1).ravel()].add((probs * w_hi).ravel())
    return out.reshape(z.shape)


VARIANTS = {"library": library, "library_fusable": library_fusable, "scatter": scatter, "uniform": uniform}


def _time(fn, args, repeats):
    out = fn(*args)
    jax.block_until_ready(out)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, default=8192)
    ap.add_argument("--atoms", type=int, default=101)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--hlo_recipe", default="", help="experiment script: also print the fused computation of the "
                    "costliest fusion (by XLA's cost analysis) in that recipe's full FastSAC-family update")
    ap.add_argument("--out", default="")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    b, k = args.batch, args.atoms
    atoms = c51.uniform_support(V_MIN, V_MAX, k, shim.get("jax"))
    inputs = (jnp.asarray(rng.normal(size=(2, b, k)), jnp.float32), jnp.asarray(rng.random(b) * 0.05, jnp.float32),
              jnp.asarray(np.where(rng.random(b) < 0.02, 0.0, 0.97), jnp.float32), atoms)
    rows, ref = [], None
    for name, fn in VARIANTS.items():
        t, out = _time(jax.jit(fn), inputs, args.repeats)
        ref = out if ref is None else ref
        err = float(jnp.max(jnp.abs(out - ref)))
        rows.append({"variant": name, "ms": t * 1e3, "max_abs_diff_vs_library": err})
        print(f"{name:16s} {t * 1e3:8.3f} ms  max |diff| vs library {err:.2e}", flush=True)
    machine = {"hostname": platform.node(), "date": datetime.datetime.now(datetime.timezone.utc).isoformat(),
               "python": platform.python_version(), "jax": jax.__version__, "jax_devices": str(jax.devices()),
               "xla_flags": os.environ.get("XLA_FLAGS", ""), "batch": b, "atoms": k}
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"machine": machine, "rows": rows}, f, indent=2)
    if args.hlo_recipe:
        _print_update_hlo(args.hlo_recipe)


def _print_update_hlo(recipe_path: str) -> None:
    sys.path.insert(0, os.path.join(REPO, "bench"))
    from learner_update import SPEC, _recipe, _replay_batch

    from unilab_jax import algos
    from unilab_jax.config import apply_overrides

    name = os.path.basename(recipe_path).split("_")[0]
    module = algos.get(name)
    config = apply_overrides(module.Config(), _recipe(recipe_path))
    learner = module.make_learner("jax", config, SPEC)
    state = learner.init(jax.random.key(0))
    batch = {kk: jnp.asarray(v) for kk, v in _replay_batch(np.random.default_rng(0), config.updates_per_call,
                                                              config.batch_size).items()}
    text = learner._update_jit.lower(state, batch).compile().as_text()
    with open(os.path.join(os.environ.get("OUT", "/tmp"), f"{name}_update_hlo.txt"), "w") as f:
        f.write(text)
    print(f"wrote the optimized HLO of the {name} update ({len(text)} chars)")


if __name__ == "__main__":
    main()
