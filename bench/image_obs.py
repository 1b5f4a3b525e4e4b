"""Image observations' costs: the rollout workers' numpy ``act`` (encoder + actor) per control step, and one JAX
learner update of SAC / RLPD with the DrQ encoder (augmentation, three encoder passes, one backward): prints a
table, writes JSON with machine info.

    python bench/image_obs.py --envs 1 8 --image 64 64 6 --out bench/results/image_obs_local.json
    python bench/image_obs.py --envs 1 8 --algos sac rlpd --batch 256 --updates 8 \\
        --out bench/results/h100/image_obs_h100.json                                     # on the GPU

``act``: median over ``max(--repeats, 20)`` calls, with one BLAS thread (what the WorkerPool gives a worker),
of ``sac.act(weights, obs [M, 32], noise, image=uint8 [M, H, W, C])`` on numpy weights (the encoder's
convolutions are ``xp.conv2d``'s im2col + one BLAS contraction each). ``update``: the first call (compile) and the
median steady call of ``learner.update`` on a random ``[U, B]`` batch with images, in milliseconds per gradient
step. The encoder is the configs' default (``--channels``, ``--strides``, ``--feature_dim``).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one BLAS thread, as in a worker
    os.environ[_var] = "1"

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import types  # noqa: E402

import numpy as np  # noqa: E402

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO not in sys.path:
    sys.path.insert(0, REPO)

from time_to_target import machine_info  # noqa: E402

from tasks.base import TaskSpec  # noqa: E402
from unilab_jax import algos, nets  # noqa: E402

OBS, ACT = 32, 7  # proprioception and actions of a Franka-sized task


def _spec(image: tuple[int, int, int]) -> types.SimpleNamespace:
    base = TaskSpec(name="image_bench", obs_dim=OBS, critic_obs_dim=OBS, action_dim=ACT, episode_length=100,
                    ctrl_dt=0.05, reward_terms=("r",))
    return types.SimpleNamespace(**{**dataclasses.asdict(base), "image_shape": image})


def _batch(rng: np.random.Generator, u: int, b: int, image: tuple[int, int, int]) -> dict[str, np.ndarray]:
    f = lambda *s: rng.normal(size=s).astype(np.float32)  # noqa: E731
    return {"obs": f(u, b, OBS), "critic_obs": f(u, b, OBS), "next_obs": f(u, b, OBS), "next_critic_obs": f(u, b, OBS),
            "action": np.tanh(f(u, b, ACT)), "reward": f(u, b), "terminated": rng.random((u, b)) < 0.01,
            "truncated": np.zeros((u, b), bool), "image": rng.integers(0, 256, (u, b, *image), dtype=np.uint8),
            "next_image": rng.integers(0, 256, (u, b, *image), dtype=np.uint8)}


def _median_seconds(fn, repeats: int) -> float:
    times = []
    fn()  # warm
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def measure(algo: str, args: argparse.Namespace, rng: np.random.Generator) -> list[dict]:
    """The numpy act rows (one per ``--envs``) and the JAX update row of ``algo``."""
    import jax

    image = tuple(args.image)
    mod = algos.get(algo)
    config = mod.Config(actor_hidden=(256, 256), critic_hidden=(256, 256), batch_size=args.batch,
                        updates_per_call=args.updates, encoder_channels=tuple(args.channels),
                        encoder_strides=tuple(args.strides), feature_dim=args.feature_dim)
    learner = algos.make_learner(algo, "jax", config, _spec(image))
    state = learner.init(jax.random.PRNGKey(0))
    weights = nets.to_numpy(learner.weights(state))
    rows = []
    for m in args.envs:
        obs, noise = rng.normal(size=(m, OBS)).astype(np.float32), rng.normal(size=(m, ACT)).astype(np.float32)
        img = rng.integers(0, 256, (m, *image), dtype=np.uint8)
        sec = _median_seconds(lambda: mod.act(weights, obs, noise, image=img), max(args.repeats, 20))  # noqa: B023
        rows.append({"what": "numpy act", "algo": algo, "envs": m, "ms": 1e3 * sec})
    batch = {k: jax.numpy.asarray(v) for k, v in _batch(rng, args.updates, args.batch, image).items()}
    box = [state]

    def call() -> None:
        box[0], _ = learner.update(box[0], batch)
        jax.block_until_ready(box[0])

    t = time.perf_counter()
    call()
    first = time.perf_counter() - t
    sec = _median_seconds(call, args.repeats)
    rows.append({"what": "jax update", "algo": algo, "batch": args.batch, "updates": args.updates,
                 "first_call_s": first, "ms_per_step": 1e3 * sec / args.updates, "backend": jax.default_backend()})
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--envs", type=int, nargs="+", default=[1, 8])
    p.add_argument("--image", type=int, nargs=3, default=[64, 64, 6], metavar=("H", "W", "C"))
    p.add_argument("--algos", nargs="+", default=["sac"])
    p.add_argument("--batch", type=int, default=128)
    p.add_argument("--updates", type=int, default=4, help="gradient steps per update call (U)")
    p.add_argument("--channels", type=int, nargs="+", default=[32, 32, 32, 32])
    p.add_argument("--strides", type=int, nargs="+", default=[2, 1, 1, 1])
    p.add_argument("--feature_dim", type=int, default=50)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--out", default="")
    args = p.parse_args()
    rng = np.random.default_rng(0)
    rows = [row for algo in args.algos for row in measure(algo, args, rng)]
    for r in rows:
        if r["what"] == "numpy act":
            print(f"{r['algo']:6s} numpy act   {r['envs']:3d} envs  {r['ms']:8.2f} ms/step")
        else:
            print(f"{r['algo']:6s} jax update  B={r['batch']} U={r['updates']}  first call {r['first_call_s']:.1f} s, "
                  f"{r['ms_per_step']:.1f} ms/gradient step ({r['backend']})")
    if args.out:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, "w") as f:
            json.dump({"args": vars(args), "rows": rows, "machine": machine_info()}, f, indent=1)


if __name__ == "__main__":
    main()
