"""Data-parallel JAX learners over the local accelerators (``--devices``), with ``jax.sharding``.

A 1-D :class:`jax.sharding.Mesh` over the first N local devices, axis ``"batch"``. :class:`DataParallel`
wraps any JAX learner whose pure update is ``learner.traced_update(state, batch) -> (state, metrics)`` (the
off-policy learners, PPO/APPO and their subclasses: the function each compiles for one device, the off-policy
ones' traced in their ``compute_dtype``, so bf16 matmuls stay bf16 here) and compiles it once more, with
``jax.jit(in_shardings=(replicated, batch-sharded), out_shardings=replicated)``:

* the batch is split along its batch axis, axis 1 of every field (``[U, B, ...]`` replay minibatches:
  B; ``[T, M, ...]`` trajectories: M, the environments), so each device holds ``1/N`` of it;
* parameters, optimizer state, normalizers and the RNG key are replicated;
* the program is the single-device one: GSPMD partitions it, so every reduction over the batch (loss
  means, normalizer statistics, hence gradients) becomes a per-device partial sum plus an all-reduce
  that XLA inserts. Results equal the single-device update up to the order of float additions.

No ``pmap`` and no per-device state copies: one global array per leaf, placed with ``jax.device_put``
(``jax.device_put_replicated`` / ``device_put_sharded`` are gone in jax 0.11). One device is not wrapped
at all (:func:`make`), so ``--devices=1`` is exactly the single-device path.

``split="critics"`` (``--device_split=critics``, off-policy learners): where splitting the batch cannot pay (at a
fixed batch per device each device does one device's work per gradient step, docs/perf/learner_scaling.md sections
2 and 6), the critic ensemble is split instead: every leaf of the state's critic fields (``CRITIC_FIELDS``: the
critics, their targets and optimizer state, ``[E, ...]`` with E members) is split along its member axis, each device
holding E / N members, and the batch, the actor and the rest are replicated. GSPMD partitions the critics' forward and
backward by member; what crosses devices per step is what mixes members (the minimum or mean over critics, the
actor's gradient through them).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from unilab_jax.algos.offpolicy import learner_common as common

AXIS = "batch"
SPLITS = ("batch", "critics")
# The off-policy learners' state fields that hold the critic ensemble (every leaf's leading axis: its members).
CRITIC_FIELDS = ("critic", "target_critic", "critic_opt")
# As the learners: the state is donated on accelerators only (unilab_jax/algos/ppo/learner_jax.py says why).
DONATE_STATE = 0 if jax.default_backend() != "cpu" else ()


def parse_devices(value: str) -> int | None:
    """``"all"`` -> None (every local device), ``"N"`` -> N >= 1; ValueError otherwise."""
    if value == "all":
        return None
    try:
        n = int(value)
    except ValueError:
        raise ValueError(f"--devices={value!r}: give 'all' or a positive number of devices") from None
    if n < 1:
        raise ValueError(f"--devices={value!r}: give 'all' or a positive number of devices")
    return n


def local_devices(n: int | None) -> list[Any]:
    """The first ``n`` local devices of JAX's default backend (all of them for None)."""
    devices = jax.local_devices()
    if n is None:
        return devices
    if n > len(devices):
        raise ValueError(f"--devices={n}: only {len(devices)} local {jax.default_backend()} device(s) exist "
                         f"({', '.join(str(d) for d in devices)})")
    return devices[:n]


def check_batch(n_devices: int, batch_axis: int, what: str) -> None:
    """ValueError unless the batch axis splits evenly over the devices."""
    if batch_axis % n_devices:
        raise ValueError(f"--devices={n_devices}: {what} ({batch_axis}) must be divisible by the number of devices")


class DataParallel:
    """A learner updated over ``devices``, its batch split (``split="batch"``) or its critic ensemble
    (``split="critics"``; see the module docstring).

    ``init``, ``update`` and ``weights`` behave as the wrapped learner's; ``from_numpy(array)`` places a
    host batch field straight onto the devices (split along axis 1, or replicated with the critics split; the
    trainer's batch sources use it in place of the shim's); ``place(state)`` places a state read from a checkpoint.
    """

    def __init__(self, learner: Any, devices: list[Any], donate_argnums: Any = (), split: str = "batch"):
        if split not in SPLITS:
            raise ValueError(f"device split must be one of {SPLITS}, got {split!r}")
        self.learner, self.split = learner, split
        if hasattr(learner, "ln_kernels"):  # "auto" on several devices: XLA's programs (make refuses "pallas")
            learner.ln_kernels = common.resolve_ln_kernels(learner.config, learner.compute_dtype, devices)
        self.config, self.spec = learner.config, learner.spec
        self.mesh = Mesh(np.asarray(devices), (AXIS,))
        self.replicated = NamedSharding(self.mesh, P())
        self.batch_sharding = NamedSharding(self.mesh, P(None, AXIS)) if split == "batch" else self.replicated
        # Where each state leaf lives: replicated, or (critics) a tree read off the learner's initial state.
        self.state_sharding: Any = self.replicated
        if split == "critics":
            self.state_sharding = critic_shardings(learner.init(jax.random.key(0)), self.mesh)
        self._update = jax.jit(learner.traced_update, in_shardings=(self.state_sharding, self.batch_sharding),
                               out_shardings=(self.state_sharding, self.replicated), donate_argnums=donate_argnums)

    @property
    def num_devices(self) -> int:
        return self.mesh.size

    def init(self, key: jax.Array) -> Any:
        return self.place(self.learner.init(key))

    def place(self, state: Any) -> Any:
        return jax.device_put(state, self.state_sharding)

    def from_numpy(self, array: Any) -> jax.Array:
        return jax.device_put(array, self.batch_sharding)

    def update(self, state: Any, batch: dict) -> tuple[Any, dict]:
        """As the wrapped learner's ``update``; ``{}`` (a replay warm-up tick) is a no-op."""
        if not batch:
            return state, {}
        return self._update(state, batch)

    def weights(self, state: Any) -> Any:
        return self.learner.weights(state)

    def precompile(self, state: Any, batch_layout: dict[str, tuple]) -> None:
        """As the wrapped learner's ``precompile``, for this program: ``state`` placed (``place``, neither read nor
        donated), minibatches of ``batch_layout`` (``{field: (shape, dtype)}``) placed as ``from_numpy`` and the
        device mirror place them."""
        batch = {k: jax.ShapeDtypeStruct(shape, jax.dtypes.canonicalize_dtype(dtype), sharding=self.batch_sharding)
                 for k, (shape, dtype) in batch_layout.items()}
        self._update.lower(state, batch).compile()

    def __getattr__(self, name: str) -> Any:  # trace_count, optimizers, ... of the wrapped learner
        return getattr(self.learner, name)


def critic_shardings(state: Any, mesh: Mesh) -> Any:
    """A sharding per leaf of ``state`` (a learner's state NamedTuple): the leaves of ``CRITIC_FIELDS`` whose leading
    axis is the ensemble's E members split along it over ``mesh``, every other leaf replicated."""
    missing = [f for f in CRITIC_FIELDS if f not in getattr(state, "_fields", ())]
    if missing:
        raise ValueError(f"--device_split=critics: the learner's state has no critic ensemble ({missing} missing)")
    members = jax.tree.leaves(state.critic)[0].shape[0]
    if members % mesh.size:
        raise ValueError(f"--device_split=critics: the ensemble's {members} critics do not divide over "
                         f"{mesh.size} devices")
    split, whole = NamedSharding(mesh, P(AXIS)), NamedSharding(mesh, P())

    def field(name: str, value: Any) -> Any:
        if name not in CRITIC_FIELDS:
            return jax.tree.map(lambda _: whole, value)
        return jax.tree.map(lambda x: split if np.ndim(x) >= 1 and x.shape[0] == members else whole, value)

    return type(state)(**{name: field(name, getattr(state, name)) for name in state._fields})


def check_kernels(config: Any, n_devices: int) -> None:
    """ValueError for Pallas LayerNorm kernels (``ln_forward`` / ``ln_backward``) on several devices: a Pallas call
    is one device's program, which XLA's SPMD partitioner does not split."""
    pallas = [f"{name}=pallas" for name in ("ln_forward", "ln_backward") if getattr(config, name, "xla") == "pallas"]
    if pallas and n_devices > 1:
        raise ValueError(f"--devices={n_devices}: {' and '.join(pallas)} run on one device only; drop them "
                         "(--config ln_forward=xla --config ln_backward=xla) or use one device")


def make(learner: Any, devices: int | None, split: str = "batch") -> Any:
    """``learner`` itself for one device (today's path, untouched), else a :class:`DataParallel` over the
    first ``devices`` local devices (None: all), split as ``split`` says."""
    chosen = local_devices(devices)
    if len(chosen) == 1:
        return learner
    check_kernels(learner.config, len(chosen))  # also here for callers that skip check_run (bench/scale_out.py)
    return DataParallel(learner, chosen, DONATE_STATE, split)


def check_run(devices: str, platform: str, config: Any, buffer: str, num_workers: int, envs_per_worker: int,
              split: str = "batch") -> int:
    """Validates ``--devices`` and ``--device_split`` for a run (before any worker starts); returns the number of
    devices.

    The batch axis that is split: a replay minibatch's ``batch_size``; a trajectory batch's environments
    (``num_workers * envs_per_worker``, every slot of a lock-step or async collect). The critics split needs an
    off-policy learner (the ensemble's size is checked against the devices when the learner is wrapped)."""
    n = parse_devices(devices)
    if platform != "jax" and devices != "1":
        raise ValueError(f"--devices={devices}: data-parallel learners are JAX's (--platform=jax)")
    if split not in SPLITS:
        raise ValueError(f"--device_split={split!r}: choose one of {SPLITS}")
    n = len(local_devices(n))
    check_kernels(config, n)
    if split == "critics":
        if buffer != "replay":
            raise ValueError("--device_split=critics: the off-policy learners' critic ensemble only")
        return n
    if buffer == "replay":
        check_batch(n, int(config.batch_size), "batch_size")
    else:
        check_batch(n, num_workers * envs_per_worker, "num_workers * envs_per_worker")
    return n


def for_run(learner: Any, run: Any, config: Any, buffer: str) -> DataParallel | None:
    """The :class:`DataParallel` learner of ``run.devices`` and ``run.device_split`` (checked), None for one
    device."""
    n = check_run(run.devices, run.platform, config, buffer, run.num_workers, run.envs_per_worker, run.device_split)
    return make(learner, n, run.device_split) if n > 1 else None
