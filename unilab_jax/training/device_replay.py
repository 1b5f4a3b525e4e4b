"""A copy of the shared-memory replay rings in accelerator memory: minibatches are sampled and gathered there.

With a GPU learner, drawing a [U, B] minibatch on the host means gathering U * B rows out of the rings
(~94 MB for FastSAC's 8 x 8192 Go1 rows) and copying them to the device for every update call: on the
H100 that took ~66 ms per call in the learner process, longer than the update itself (27 ms). The
mirror instead copies each transition to the device once, when it is new (a few MB per call), and the
update's minibatch is one device-side gather of sampled row indices.

* ``sync()``: the rows the workers committed since the previous call
  (:meth:`ReplayBuffer.read_new`, the same lock-free protocol as host sampling) are written to their
  slots of one device array per field, laid out like the rings ([W * C, ...]); each worker's window
  of intact rows ``[lo, hi)`` is kept on the host. In two halves for the training loop: ``stage()`` (the
  prefetch thread: copy out of the rings, start the upload) and ``write(upload)`` (the learner's thread, just
  before the update). The scatter donates the mirror, so a thread that dispatches it while an update runs
  waits for that update (in-run on the H100 machine the prefetch thread spent ~14 ms a call there, and the
  learner then waited for its batch); dispatched by the learner's own thread between updates, it waits for
  nothing.
* ``sample(shape, rng)``: a minibatch ``{field: [*shape, ...]}`` of rows drawn uniformly over the union of
  the windows (with replacement), drawn AND gathered on the device in one jitted call: the host sends the
  windows (two numbers per worker) and one seed taken from the caller's numpy generator, so a seeded run
  draws reproducibly, and no index array crosses to the device. In halves: ``draw`` (host values) and ``take``.

Uploads are padded to a power-of-two number of rows (padding rows index past the end and are dropped)
so the donated scatter compiles for a handful of sizes only. Memory: the rings' size once more on the
device (2M Go1 transitions: ~2.9 GB).

With a data-parallel learner (``parallel``, a :class:`~unilab_jax.training.sharding.DataParallel`, ``--devices`` > 1)
the mirror is replicated on every device of the mesh (each new row is uploaded to each device; memory the
rings' size per device) and ``take`` returns the minibatch split along B, as the sharded update takes it:
each device gathers its own columns from its local copy, with no traffic between devices, and the rows
drawn are exactly those of one device for the same generator.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

MIN_UPLOAD_ROWS = 1024


def _gather_impl(data: dict, index: jax.Array) -> dict:
    return {k: v[index] for k, v in data.items()}


def _sample_impl(data: dict, lo: jax.Array, sizes: jax.Array, seed: jax.Array, shape: tuple, capacity: int) -> dict:
    """Rows drawn uniformly over the workers' windows ``[lo, lo + size)`` (ring slots modulo ``capacity``)."""
    ends = jnp.cumsum(sizes)
    flat = jax.random.randint(jax.random.key(seed), shape, 0, ends[-1], jnp.int32)
    worker = jnp.searchsorted(ends, flat, side="right")
    row = lo[worker] + flat - (ends - sizes)[worker]
    return _gather_impl(data, worker * capacity + row % capacity)


_sample = jax.jit(_sample_impl, static_argnums=(4, 5))


def _scatter_impl(data: dict, slots: jax.Array, rows: dict) -> dict:
    return {k: v.at[slots].set(rows[k], mode="drop") for k, v in data.items()}


_scatter = jax.jit(_scatter_impl, donate_argnums=0)


class DeviceReplay:
    """Mirror of a :class:`~unilab_jax.runtime.buffers.ReplayBuffer`'s ``fields`` on the default device."""

    def __init__(self, ring: Any, fields: Iterable[str], parallel: Any = None):
        self._ring = ring
        self.fields = tuple(fields)
        w, c = ring.num_workers, ring.capacity
        self._rows = w * c
        # 64-bit fields become 32-bit unless jax_enable_x64 (the learner's fields are float32 and bool).
        self.data = {f: jnp.zeros((self._rows, *ring.fields[f][0]), jax.dtypes.canonicalize_dtype(ring.fields[f][1]))
                     for f in self.fields}
        self._scatter, self._sample = _scatter, _sample
        self._placement = None  # where uploads go (the default device, or every device of the mesh)
        if parallel is not None:
            self._placement = parallel.replicated
            self.data = jax.device_put(self.data, parallel.replicated)
            self._scatter = jax.jit(_scatter_impl, donate_argnums=0, out_shardings=parallel.replicated)
            self._sample = jax.jit(_sample_impl, static_argnums=(4, 5), out_shardings=parallel.batch_sharding)
        self.lo = np.zeros(w, np.int64)  # per worker: global rows [lo, hi) are intact on the device
        self.hi = np.zeros(w, np.int64)  # (hi: the worker's count at the last sync)
        self.uploaded = 0  # rows copied to the device so far

    @property
    def size(self) -> int:
        """Rows available to ``sample``."""
        return int(np.sum(self.hi - self.lo))

    def stage(self) -> tuple[Any, int]:
        """Copies the rows committed since the last call out of the rings and starts their upload (the prefetch
        thread's half of a sync); returns ``(upload, rows)``. The windows move at once: ``write(upload)`` must put
        the rows in place before the next ``take`` (the sampling thread's half)."""
        new = self._ring.read_new(self.hi, self.fields)
        n = int(new["slots"].size)
        upload = None
        if n:
            padded = max(MIN_UPLOAD_ROWS, 1 << (n - 1).bit_length())
            slots = np.full(padded, self._rows, np.int32)  # out of range: dropped by the scatter
            slots[:n] = new["slots"]
            rows = {}
            for f in self.fields:
                a = new["rows"][f]
                pad = np.zeros((padded, *a.shape[1:]), a.dtype)
                pad[:n] = a
                rows[f] = pad
            upload = jax.device_put((slots, rows), self._placement)
            self.uploaded += n
        self.lo, self.hi = new["lo"], new["hi"]
        return upload, n

    def write(self, upload: Any) -> None:
        """Scatters a staged upload into the mirror (in the order the uploads were staged)."""
        if upload is not None:
            self.data = self._scatter(self.data, *upload)

    def sync(self) -> int:
        """Copies the rows committed since the last call to the device (``stage`` then ``write``); returns how many."""
        upload, n = self.stage()
        self.write(upload)
        return n

    def draw(self, shape: tuple[int, ...], rng: np.random.Generator) -> tuple:
        """What ``take`` needs to draw a minibatch ``[*shape]`` over the current windows: the windows and one seed
        from ``rng`` (host values only, so the prefetch thread can draw while the device is busy)."""
        sizes = self.hi - self.lo
        if sizes.sum() <= 0:
            raise ValueError("the device replay mirror is empty: call sync() once the rings hold data")
        seed = np.uint32(rng.integers(0, 2**32))
        return self.lo.astype(np.int32) % self._ring.capacity, sizes.astype(np.int32), seed, tuple(shape)

    def take(self, draw: tuple) -> dict[str, jax.Array]:
        """The minibatch of ``draw``, drawn and gathered on the device in one jitted call."""
        lo, sizes, seed, shape = draw
        return self._sample(self.data, lo, sizes, seed, shape, self._ring.capacity)

    def sample(self, shape: tuple[int, ...], rng: np.random.Generator) -> dict[str, jax.Array]:
        """A minibatch ``{field: [*shape, ...]}`` drawn uniformly over the intact rows of every worker, on the device
        (``draw`` then ``take``: the same generator state draws the same rows)."""
        return self.take(self.draw(shape, rng))
