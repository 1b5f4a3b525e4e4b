"""Lock-free single-producer/single-consumer rings of slot indices in shared memory.

Python has no atomics, so the rings are built from two facts every supported CPU gives us (x86-64
and arm64, including Apple Silicon's weak memory order) and a checksum that makes the rest safe:

1. **A naturally aligned 8-byte store or load is single-copy atomic.** A reader sees the old word or
   the new word, never a mix. numpy assigns one element of an aligned ``int64`` array with one
   8-byte store (``arr[i] = v`` on a 1-element index is a typed copy, not a byte loop).
2. **Coherence.** Each memory location has one total order of writes that every core agrees on, and
   a core's successive reads of one location never go back in that order. Stores become visible to
   other cores eventually (seconds at the very most, nanoseconds in practice).

What we do NOT assume: that stores to *different* locations become visible in program order. On
arm64 the consumer may see the "slot 3 is full" entry before it sees the slot's data.

The ring
--------
One ``int64`` array per ring: ``words[0]`` is the consumer's read count (written only by the
consumer), ``words[8]`` the producer's write count (written only by the producer; informational),
``words[16:16+cap]`` the entries (``cap`` a power of two). Each entry is ONE word packing
``(sequence << 32) | value`` where ``sequence = write_count mod 2**31``; the producer publishes with
a single store. The consumer at read count ``r`` accepts the entry at ``r % cap`` only if its
sequence equals ``r mod 2**31``; otherwise the ring is empty. Because sequence and value travel in
one atomic word, the consumer can never accept a value whose entry is incomplete or left over from
the previous lap (entries start as -1, whose sequence 0xFFFFFFFF never matches). The producer
refuses to write when ``write_count - read_count >= cap`` (full), and the consumer bumps its read
count only after it has read the entry, so an entry is never overwritten before it is consumed.
No locks, no system calls, no pickling per operation; waits spin briefly and then sleep.

The data behind an index
------------------------
The slot data written before publishing is NOT ordered with the publishing store by (1) or (2).
It is protected by a checksum: the producer writes the data, computes :func:`checksum` of the slot
bytes mixed with the sequence number the slot is published under, stores it in the slot's header,
and only then publishes. The consumer, having read the entry for sequence ``s``, recomputes the
checksum of the slot bytes mixed with ``s`` and compares with the header; on a mismatch (some of the
new data, or the new header, not yet visible) it re-reads until they agree or a timeout passes.
Mixing in the sequence means data and header left from the slot's previous use can never pass for
the new data. Once the checksum matches, coherence (2) guarantees later reads of those bytes see
the verified values or newer ones, and there are no newer ones: the producer does not touch the
slot again until the consumer hands the index back through the opposite ring. A torn read passes
only if the wrapped 64-bit sum AND the 64-bit xor of the old and new words coincide (a random
coincidence has probability ~2**-64 per comparison, and the mixed-in sequence rules out replays).

Between the data writes and the publishing store, and after reading an entry before reading the
data, both sides call :func:`fence`: acquiring and releasing a ``threading.Lock`` executes atomic
read-modify-write instructions with acquire/release semantics (a full barrier on x86, ``ldaxr``/
``stlxr`` or ``casal`` plus ``dmb`` on arm64 in glibc/libpthread and libdispatch). The fence makes
the checksum succeed on the first try in practice; the checksum is what makes the protocol correct
even if the fence were not a barrier.

Handing a slot back (consumer -> producer through the other ring) needs the opposite order: the
consumer's reads of the slot must complete before the producer overwrites it. The consumer copies
the data out, calls :func:`fence`, then publishes the index; a store is never made visible before
earlier loads complete across a full barrier.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

__all__ = ["SpscRing", "RingTimeout", "StopRequested", "checksum", "fence", "mix64", "ring_words"]

_SEQ_MASK = 0x7FFFFFFF
_VAL_MASK = 0xFFFFFFFF
_HEAD, _TAIL, _ENTRIES = 0, 8, 16  # head and tail on separate cache lines
_M64 = (1 << 64) - 1

_FENCE_LOCK = threading.Lock()


def fence() -> None:
    """A full memory barrier in practice (uncontended lock acquire + release)."""
    _FENCE_LOCK.acquire()
    _FENCE_LOCK.release()


def mix64(x: int) -> int:
    """splitmix64 finalizer: a bijective 64-bit mixer (python ints)."""
    x &= _M64
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _M64
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _M64
    return x ^ (x >> 31)


def checksum(data: np.ndarray, seq: int = 0) -> int:
    """64-bit checksum of a C-contiguous byte range whose length is a multiple of 8, mixed with ``seq``.

    Wrapped uint64 sum and xor of the words (both memory-bandwidth bound in numpy, ~GB/s),
    combined with the length and the sequence number through splitmix64.
    """
    words = data.view(np.uint64) if data.dtype != np.uint64 else data
    s = int(words.sum(dtype=np.uint64))
    x = int(np.bitwise_xor.reduce(words)) if words.size else 0
    h = mix64(s ^ mix64(words.size + 0x9E3779B97F4A7C15))
    h = mix64(h ^ x)
    return mix64(h ^ (int(seq) * 0xD6E8FEB86659FD93 & _M64)) & 0x7FFFFFFFFFFFFFFF  # fits int64


class RingTimeout(TimeoutError):
    """A ring wait ran past its deadline."""


class StopRequested(Exception):
    """A wait was given up because its owner asked to stop (a signal, say)."""


def ring_words(capacity: int) -> int:
    """Number of int64 words of shared memory a ring of (at least) ``capacity`` entries needs."""
    return _ENTRIES + _pow2(capacity)


def _pow2(n: int) -> int:
    n = max(int(n), 1)
    return 1 << (n - 1).bit_length()


class SpscRing:
    """One single-producer / single-consumer ring over an int64 view ``words`` of shared memory.

    Create the view with :func:`ring_words` words, poison-filled (-1) by ``SharedArrays``; call
    :meth:`init` once (creator) to zero the counters. Each side keeps no private state: its counter
    lives in shared memory (it is the only writer of it), so a respawned process can take over.
    """

    def __init__(self, words: np.ndarray):
        if words.dtype != np.int64 or words.ndim != 1:
            raise TypeError("a ring needs a 1-D int64 view")
        if words.ctypes.data % 8:
            raise ValueError("ring words must be 8-byte aligned")
        self.words = words
        self.capacity = words.size - _ENTRIES
        if self.capacity <= 0 or self.capacity & (self.capacity - 1):
            raise ValueError(f"ring capacity must be a power of two, got {self.capacity}")
        self._mask = self.capacity - 1
        self.entries = words[_ENTRIES:]

    def init(self) -> None:
        """Creator only, before any other process uses the ring."""
        self.entries[:] = -1
        self.words[_HEAD] = 0
        self.words[_TAIL] = 0

    # ---- producer -----------------------------------------------------------------------------
    def push(self, value: int) -> int | None:
        """Publishes ``value`` (0 <= value < 2**32); returns its sequence number, or None if full.

        Call :func:`fence` between writing the data behind ``value`` and this call (``push`` does it).
        """
        if not 0 <= value <= _VAL_MASK:
            raise ValueError(f"ring values are uint32, got {value}")
        w = int(self.words[_TAIL])
        if w - int(self.words[_HEAD]) >= self.capacity:
            return None
        fence()
        self.entries[w & self._mask] = ((w & _SEQ_MASK) << 32) | value  # the single publishing store
        self.words[_TAIL] = w + 1
        return w

    def next_sequence(self) -> int:
        """Sequence number the next :meth:`push` will publish under (producer side)."""
        return int(self.words[_TAIL])

    # ---- consumer -----------------------------------------------------------------------------
    def peek(self) -> tuple[int, int] | None:
        """(value, sequence) of the next entry without consuming it, or None if empty."""
        r = int(self.words[_HEAD])
        e = int(self.entries[r & self._mask])
        if e < 0 or (e >> 32) != (r & _SEQ_MASK):
            return None
        fence()
        return e & _VAL_MASK, r

    def advance(self) -> None:
        """Consumes the entry returned by :meth:`peek` (after its data has been read)."""
        fence()
        self.words[_HEAD] = int(self.words[_HEAD]) + 1

    def pop(self) -> tuple[int, int] | None:
        """Consumes and returns (value, sequence) of the next entry, or None if empty."""
        got = self.peek()
        if got is not None:
            self.advance()
        return got

    def pop_wait(self, timeout: float | None = None, check: Callable[[], None] | None = None,
                 poll: float = 0.05) -> tuple[int, int]:
        """Blocks until an entry arrives; ``check()`` runs every ``poll`` s (and may raise)."""
        return wait_for(self.pop, timeout=timeout, check=check, poll=poll, what="ring entry")

    # ---- recovery (one side's process is dead) ---------------------------------------------------
    def recover_producer(self) -> bool:
        """Completes a push whose producer died between its publishing store and its count update.

        Without this a respawned producer would publish its next entry under the sequence the
        consumer has already read, and the consumer would never accept it. Call only while no
        producer runs. Returns True if a push was completed.
        """
        w = int(self.words[_TAIL])
        e = int(self.entries[w & self._mask])
        if e >= 0 and (e >> 32) == (w & _SEQ_MASK):
            self.words[_TAIL] = w + 1
            return True
        return False

    def pending(self) -> list[int]:
        """Values published and not yet consumed (exact while one side is stopped)."""
        return [int(self.entries[i & self._mask]) & _VAL_MASK for i in range(self.read_count, self.write_count)]

    def __len__(self) -> int:
        """Entries published and not yet consumed (a snapshot)."""
        return max(0, int(self.words[_TAIL]) - int(self.words[_HEAD]))

    @property
    def read_count(self) -> int:
        return int(self.words[_HEAD])

    @property
    def write_count(self) -> int:
        return int(self.words[_TAIL])


def wait_for(fn: Callable[[], object], timeout: float | None = None, check: Callable[[], None] | None = None,
             poll: float = 0.05, what: str = "condition"):
    """Calls ``fn()`` until it returns something other than None; spins briefly, then sleeps (<= 1 ms).

    ``check()`` runs every ``poll`` seconds of waiting (e.g. to notice a dead peer or a stop flag)
    and may raise. Raises :class:`RingTimeout` after ``timeout`` seconds.
    """
    got = fn()
    if got is not None:
        return got
    start = time.monotonic()
    next_check = start + poll
    spins = 0
    sleep = 20e-6
    while True:
        got = fn()
        if got is not None:
            return got
        spins += 1
        if spins > 200:
            time.sleep(sleep)
            sleep = min(sleep * 2, 1e-3)
        now = time.monotonic()
        if now >= next_check:
            next_check = now + poll
            if check is not None:
                check()
            if timeout is not None and now - start > timeout:
                raise RingTimeout(f"timed out after {timeout:.1f} s waiting for a {what}")
