"""The array-API shim: one namespace, three backends (numpy, jax, mlx).

Algorithm kernels (``unilab_jax.core``) and task math (``tasks``) import only this module.
A kernel finds its backend from its inputs::

    from unilab_jax import xp as shim

    def loss(x):
        xp = shim.namespace(x)      # numpy, jax or mlx backend, by the array type of x
        return xp.mean(xp.square(x))

Each backend forwards the Python array API names (``xp.exp``, ``xp.concat``, ``xp.astype`` ...) to
its array library and adds the few things the standard lacks, with the same meaning everywhere:

* keyed random numbers: ``xp.random.key(seed)``, ``split(key, n)``, ``normal(key, shape)``,
  ``uniform(key, shape, low, high)``, ``randint(key, shape, low, high)`` -- explicit keys on every
  backend, never a global generator;
* ``value_and_grad(fn, has_aux=False)`` (gradient of the first argument), ``jit(fn)``,
  ``stop_gradient``, ``materialize`` (a fusion barrier under jit, identity elsewhere);
* tree utilities ``tree_map`` / ``tree_leaves`` over dicts, lists, tuples and NamedTuples;
* ``scan(f, init, xs, reverse=False)`` over the leading axis;
* a few numerics outside the standard: ``logsumexp``, ``softmax``, ``log_softmax``, ``softplus``,
  ``relu``, ``elu``, ``one_hot``, and ``conv2d(x [B, H, W, Cin], w [kh, kw, Cin, Cout], stride)`` (VALID
  padding, channels last; differentiable on jax and mlx);
* conversion: ``asnumpy(x)`` and ``from_numpy(x)``;
* threads: ``end_thread()`` frees the calling thread's per-thread backend state (MLX's streams); call it
  last in a thread that ran backend work, then join the thread;
* network layers: ``activation(name, x)``, ``layer_norm(x, g, o)``, ``dense(x, w, b, g, o, activation)``;
* jax only: ``with xp.compute_dtype("bfloat16"):`` makes ``xp.matmul`` of float32 arrays traced in that
  block multiply in bfloat16 with float32 accumulation and float32 results (forward and backward),
  ``conv2d`` convolve bf16 operands into bf16 results (returned as float32; the backward convolutions in bf16
  too), and ``dense`` with LayerNorm and ReLU keep its activations in bf16 between matmuls (float32 statistics), so
  norms, softmax, losses and the optimizer stay float32 (``learner_jax``'s ``compute_dtype``;
  ``unilab_jax.mixed_precision``).

Importing this module imports numpy only. ``get("jax")`` imports jax on demand and ``get("mlx")``
imports ``unilab_mlx``, so workers stay numpy-only and a Mac without jax can use MLX.
"""

from __future__ import annotations

import contextlib
import importlib
import math
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

__all__ = ["Backend", "get", "namespace", "register_backend", "available", "end_thread", "tree_map", "tree_leaves"]

ACTIVATIONS = ("elu", "relu", "tanh", "silu", "identity")  # Backend.activation's names
_FACTORIES: dict[str, Callable[[], Backend]] = {}
_INSTANCES: dict[str, Backend] = {}
# Modules that register a backend when imported (so `get` can load them lazily).
_LAZY_MODULES = {"mlx": "unilab_mlx.backend"}


# ---------------------------------------------------------------------------------------------
# Pure-Python pytree utilities: dicts (sorted keys), lists, tuples, NamedTuples, None; leaves are
# everything else. The jax backend uses jax.tree_util instead so registered pytrees also work.
# ---------------------------------------------------------------------------------------------
def _is_namedtuple(x: Any) -> bool:
    return isinstance(x, tuple) and hasattr(x, "_fields")


def tree_map(fn: Callable, tree: Any, *rest: Any) -> Any:
    """Applies ``fn`` to corresponding leaves of ``tree`` and ``rest``; structure must match."""
    if isinstance(tree, dict):
        for r in rest:
            if not isinstance(r, dict) or r.keys() != tree.keys():
                raise ValueError(f"tree structure mismatch: keys {sorted(tree)} vs {r!r:.200}")
        return {k: tree_map(fn, tree[k], *(r[k] for r in rest)) for k in tree}
    if _is_namedtuple(tree):
        return type(tree)(*(tree_map(fn, *xs) for xs in zip(tree, *rest, strict=True)))
    if isinstance(tree, list | tuple):
        for r in rest:
            if len(r) != len(tree):
                raise ValueError(f"tree structure mismatch: length {len(tree)} vs {len(r)}")
        return type(tree)(tree_map(fn, *xs) for xs in zip(tree, *rest, strict=True))
    if tree is None:
        return None
    return fn(tree, *rest)


def tree_leaves(tree: Any) -> list:
    """Leaves of ``tree`` in the order ``tree_map`` visits them (dict keys sorted)."""
    out: list = []
    if isinstance(tree, dict):
        for k in sorted(tree):
            out.extend(tree_leaves(tree[k]))
    elif isinstance(tree, list | tuple):
        for x in tree:
            out.extend(tree_leaves(x))
    elif tree is not None:
        out.append(tree)
    return out


def tree_paths(tree: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """(path, leaf) pairs, paths like ``layers/0/w``; used to name mismatched leaves."""
    out: list[tuple[str, Any]] = []
    if isinstance(tree, dict):
        for k in sorted(tree):
            out.extend(tree_paths(tree[k], f"{prefix}{k}/"))
    elif _is_namedtuple(tree):
        for k, v in zip(tree._fields, tree, strict=True):
            out.extend(tree_paths(v, f"{prefix}{k}/"))
    elif isinstance(tree, list | tuple):
        for i, v in enumerate(tree):
            out.extend(tree_paths(v, f"{prefix}{i}/"))
    elif tree is not None:
        out.append((prefix.rstrip("/"), tree))
    return out


class Backend:
    """One backend: array-API names forwarded to ``ns`` plus the shim's extras.

    Subclasses set ``name``, ``ns`` (the array namespace) and ``random`` and implement the extras.
    """

    name: str = "?"
    ns: Any = None
    random: Any = None
    float32: Any = None
    int32: Any = None
    uint32: Any = None
    bool: Any = None
    pi = math.pi
    e = math.e
    inf = math.inf
    nan = math.nan

    def __getattr__(self, attr: str) -> Any:
        # Only called for names not defined on the class: forward to the array namespace.
        ns = object.__getattribute__(self, "ns")
        try:
            return getattr(ns, attr)
        except AttributeError:
            raise AttributeError(f"the {self.name} backend of the shim has no {attr!r}") from None

    def __repr__(self) -> str:
        return f"<unilab_jax.xp backend {self.name!r}>"

    # ---- extras every backend implements ------------------------------------------------------
    def owns(self, x: Any) -> bool:
        raise NotImplementedError

    def asnumpy(self, x: Any) -> np.ndarray:
        return np.asarray(x)

    def from_numpy(self, x: Any, dtype: Any = None) -> Any:
        return self.asarray(x, dtype=dtype)

    def tree_map(self, fn: Callable, tree: Any, *rest: Any) -> Any:
        return tree_map(fn, tree, *rest)

    def tree_leaves(self, tree: Any) -> list:
        return tree_leaves(tree)

    def scan(self, f: Callable, init: Any, xs: Any, reverse: bool = False) -> tuple[Any, Any]:
        """``carry, y = f(carry, x)`` over the leading axis of ``xs`` (a pytree); ys are stacked."""
        leaves = tree_leaves(xs)
        n = int(leaves[0].shape[0])
        order = range(n - 1, -1, -1) if reverse else range(n)
        carry, ys = init, [None] * n
        for t in order:
            # a[t, ...]: the array API does not define a[t] on arrays of rank > 1.
            carry, ys[t] = f(carry, tree_map(lambda a, t=t: a[t, ...], xs))
        stacked = tree_map(lambda *ys_t: self.stack(list(ys_t)), *ys) if n else None
        return carry, stacked

    def logsumexp(self, x: Any, axis: int = -1, keepdims: bool = False) -> Any:
        m = self.stop_gradient(self.max(x, axis=axis, keepdims=True))
        m = self.where(self.isfinite(m), m, self.zeros_like(m))
        out = self.log(self.sum(self.exp(x - m), axis=axis, keepdims=True)) + m
        return out if keepdims else self.squeeze(out, axis=axis)

    def log_softmax(self, x: Any, axis: int = -1) -> Any:
        return x - self.logsumexp(x, axis=axis, keepdims=True)

    def softmax(self, x: Any, axis: int = -1) -> Any:
        return self.exp(self.log_softmax(x, axis=axis))

    def softplus(self, x: Any) -> Any:
        return self.logaddexp(x, self.zeros_like(x))

    def relu(self, x: Any) -> Any:
        return self.maximum(x, self.zeros_like(x))

    def elu(self, x: Any) -> Any:
        return self.where(x > 0, x, self.expm1(self.minimum(x, self.zeros_like(x))))

    def activation(self, name: str, x: Any) -> Any:
        """The hidden activation ``name`` (one of ``ACTIVATIONS``) of ``x``."""
        if name == "elu":
            return self.elu(x)
        if name == "relu":
            return self.relu(x)
        if name == "tanh":
            return self.tanh(x)
        if name == "silu":
            return x / (1.0 + self.exp(-x))
        if name == "identity":
            return x
        raise ValueError(f"unknown activation {name!r}; choose from {ACTIVATIONS}")

    def layer_norm(self, x: Any, g: Any, o: Any, eps: float = 1e-5) -> Any:
        """LayerNorm over the last axis with scale ``g`` and offset ``o``."""
        mu = self.mean(x, axis=-1, keepdims=True)
        var = self.mean(self.square(x - mu), axis=-1, keepdims=True)
        return (x - mu) / self.sqrt(var + eps) * g + o

    def dense(self, x: Any, w: Any, b: Any, g: Any = None, o: Any = None, activation: str = "identity") -> Any:
        """One MLP layer: ``activation(LayerNorm(x @ w + b) * g + o)``, without the LayerNorm when ``g`` is
        None. The jax backend runs it as bf16 kernels under ``compute_dtype("bfloat16")``
        (``unilab_jax.mixed_precision``)."""
        x = self.matmul(x, w) + b
        if g is not None:
            x = self.layer_norm(x, g, o)
        return self.activation(activation, x)

    def one_hot(self, idx: Any, n: int, dtype: Any = None) -> Any:
        dtype = self.float32 if dtype is None else dtype
        return self.astype(self.expand_dims(idx, axis=-1) == self.arange(n), dtype)

    def stop_gradient(self, x: Any) -> Any:
        return x

    def materialize(self, tree: Any) -> Any:
        """``tree`` unchanged; under a compiler (jax) the values are computed once, in memory, before any
        consumer runs, instead of being fused into (and recomputed by) each consumer. Use it where a
        cheap reduction feeds a large broadcast (XLA may otherwise redo the reduction per output).
        """
        return tree

    def jit(self, fn: Callable, **kwargs: Any) -> Callable:
        return fn

    def value_and_grad(self, fn: Callable, has_aux: bool = False) -> Callable:
        raise NotImplementedError(f"the {self.name} backend has no automatic differentiation")

    def end_thread(self) -> None:
        """Frees the calling thread's state in this backend (none unless the backend keeps some)."""


# ---------------------------------------------------------------------------------------------
# numpy
# ---------------------------------------------------------------------------------------------
class _NumpyRandom:
    """Keyed random numbers on numpy: a key is a uint32[2] array feeding a Philox generator."""

    @staticmethod
    def key(seed: int) -> np.ndarray:
        s = int(seed) & 0xFFFFFFFFFFFFFFFF
        return np.array([s >> 32, s & 0xFFFFFFFF], dtype=np.uint32)

    @staticmethod
    def _gen(key: np.ndarray) -> np.random.Generator:
        k = np.asarray(key, dtype=np.uint32)
        return np.random.Generator(np.random.Philox(key=int(k[0]) << 32 | int(k[1])))

    def split(self, key: np.ndarray, num: int = 2) -> np.ndarray:
        return self._gen(key).integers(0, 2**32, size=(num, 2), dtype=np.uint32)

    def normal(self, key: np.ndarray, shape: tuple = (), dtype: Any = np.float32) -> np.ndarray:
        return self._gen(key).standard_normal(shape, dtype=np.float64).astype(dtype)

    def uniform(self, key, shape=(), low=0.0, high=1.0, dtype: Any = np.float32) -> np.ndarray:
        return self._gen(key).uniform(low, high, size=shape).astype(dtype)

    def randint(self, key, shape, low, high, dtype: Any = np.int32) -> np.ndarray:
        return self._gen(key).integers(low, high, size=shape).astype(dtype)


class NumpyBackend(Backend):
    name = "numpy"
    ns = np
    random = _NumpyRandom()
    float32, int32, uint32, bool = np.float32, np.int32, np.uint32, np.bool_

    def owns(self, x: Any) -> bool:
        return isinstance(x, np.ndarray | np.generic)

    def asarray(self, x: Any, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        return np.asarray(x, dtype=dtype) if copy is None else np.array(x, dtype=dtype, copy=copy)

    def conv2d(self, x: np.ndarray, w: np.ndarray, stride: int = 1) -> np.ndarray:
        """2-D cross-correlation, VALID padding, channels last: ``x [B, H, W, Cin]``, ``w [kh, kw, Cin, Cout]``
        -> ``[B, (H - kh) // stride + 1, (W - kw) // stride + 1, Cout]``."""
        # im2col: a strided view of every kh x kw window [B, H', W', Cin, kh, kw], one BLAS contraction.
        kh, kw = int(w.shape[0]), int(w.shape[1])
        windows = np.lib.stride_tricks.sliding_window_view(x, (kh, kw), axis=(1, 2))[:, ::stride, ::stride]
        return np.tensordot(windows, w, axes=((4, 5, 3), (0, 1, 2)))


# ---------------------------------------------------------------------------------------------
# jax (loaded on demand)
# ---------------------------------------------------------------------------------------------
class _JaxRandom:
    def __init__(self, jax: Any):
        self._r = jax.random
        self._jnp = jax.numpy

    def key(self, seed: int) -> Any:
        return self._r.PRNGKey(seed)

    def split(self, key: Any, num: int = 2) -> Any:
        return self._r.split(key, num)

    def normal(self, key, shape=(), dtype: Any = None) -> Any:
        return self._r.normal(key, shape, dtype=dtype or self._jnp.float32)

    def uniform(self, key, shape=(), low=0.0, high=1.0, dtype: Any = None) -> Any:
        return self._r.uniform(key, shape, dtype=dtype or self._jnp.float32, minval=low, maxval=high)

    def randint(self, key, shape, low, high, dtype: Any = None) -> Any:
        return self._r.randint(key, shape, low, high, dtype=dtype or self._jnp.int32)


COMPUTE_DTYPES = ("float32", "bfloat16")


class JaxBackend(Backend):
    name = "jax"

    def __init__(self) -> None:
        import jax
        import jax.numpy as jnp

        self._jax = jax
        self.ns = jnp
        self.random = _JaxRandom(jax)
        self.float32, self.int32, self.uint32, self.bool = jnp.float32, jnp.int32, jnp.uint32, jnp.bool_
        self._local = threading.local()  # .low: True while compute_dtype("bfloat16") is active
        self._mp = importlib.import_module("unilab_jax.mixed_precision")  # the bf16 kernels (imports jax)

    @contextlib.contextmanager
    def compute_dtype(self, name: str) -> Iterator[None]:
        """Within the block (this thread, at trace time), ``matmul`` of two float32 arrays of rank >= 2
        multiplies in ``name`` ("bfloat16") with float32 accumulation and result, and ``conv2d`` convolves in
        bf16 (``mixed_precision.conv2d``); "float32" changes nothing (the plain ``jnp.matmul`` and convolution)."""
        if name not in COMPUTE_DTYPES:
            raise ValueError(f"compute_dtype must be one of {COMPUTE_DTYPES}, got {name!r}")
        previous = getattr(self._local, "low", False)
        self._local.low = name == "bfloat16"
        try:
            yield
        finally:
            self._local.low = previous

    def _low(self, *arrays: Any) -> bool:
        """bf16 kernels apply: compute_dtype("bfloat16") is active and every operand is a float32 or bf16 matrix."""
        return getattr(self._local, "low", False) and all(
            x.ndim >= 2 and x.dtype in (self.float32, self.ns.bfloat16) for x in arrays)

    def matmul(self, a: Any, b: Any) -> Any:
        if not self._low(a, b):
            return self.ns.matmul(a, b)
        return self._mp.matmul(a, b, self.float32)

    def dense(self, x: Any, w: Any, b: Any, g: Any = None, o: Any = None, activation: str = "identity") -> Any:
        if g is None or activation != "relu" or not self._low(x, w):
            return super().dense(x, w, b, g, o, activation)
        return self._mp.layer_norm_relu(self._mp.matmul(x, w, self._mp.BF16), b, g, o)

    def owns(self, x: Any) -> bool:
        return isinstance(x, self._jax.Array)

    def asnumpy(self, x: Any) -> np.ndarray:
        return np.asarray(self._jax.device_get(x))

    def from_numpy(self, x: Any, dtype: Any = None) -> Any:
        return self.ns.asarray(np.asarray(x), dtype=dtype)

    def tree_map(self, fn: Callable, tree: Any, *rest: Any) -> Any:
        return self._jax.tree_util.tree_map(fn, tree, *rest)

    def tree_leaves(self, tree: Any) -> list:
        return self._jax.tree_util.tree_leaves(tree)

    def scan(self, f: Callable, init: Any, xs: Any, reverse: bool = False) -> tuple[Any, Any]:
        return self._jax.lax.scan(f, init, xs, reverse=reverse)

    def logsumexp(self, x: Any, axis: int = -1, keepdims: bool = False) -> Any:
        return self._jax.nn.logsumexp(x, axis=axis, keepdims=keepdims)

    def log_softmax(self, x: Any, axis: int = -1) -> Any:
        return self._jax.nn.log_softmax(x, axis=axis)

    def softmax(self, x: Any, axis: int = -1) -> Any:
        return self._jax.nn.softmax(x, axis=axis)

    def softplus(self, x: Any) -> Any:
        return self._jax.nn.softplus(x)

    def stop_gradient(self, x: Any) -> Any:
        return self._jax.lax.stop_gradient(x)

    def conv2d(self, x: Any, w: Any, stride: int = 1) -> Any:
        if self._low(x, w):
            return self._mp.conv2d(x, w, stride)
        return self._jax.lax.conv_general_dilated(x, w, (stride, stride), "VALID",
                                                  dimension_numbers=("NHWC", "HWIO", "NHWC"))

    def materialize(self, tree: Any) -> Any:
        return self._jax.lax.optimization_barrier(tree)

    def jit(self, fn: Callable, **kwargs: Any) -> Callable:
        return self._jax.jit(fn, **kwargs)

    def value_and_grad(self, fn: Callable, has_aux: bool = False) -> Callable:
        return self._jax.value_and_grad(fn, has_aux=has_aux)


# ---------------------------------------------------------------------------------------------
# Registry
# ---------------------------------------------------------------------------------------------
def register_backend(name: str, factory: Callable[[], Backend]) -> None:
    """Registers a backend factory (called once, on first ``get(name)``)."""
    _FACTORIES[name] = factory
    _INSTANCES.pop(name, None)


register_backend("numpy", NumpyBackend)
register_backend("jax", JaxBackend)


def end_thread() -> None:
    """The last call of a thread that ran backend work: frees its per-thread state while Python is alive.

    MLX keeps streams per thread. Left to the thread's C++ exit destructors, they can run while the
    main thread finalizes the interpreter; a destructor that then waits for the GIL is unwound by
    ``PyThread_exit_thread`` through a noexcept frame, and the process aborts ("terminate called
    without an active exception", exit -6) after the run's work is done. Join the thread afterwards.
    """
    if "mlx.core" in sys.modules:  # MLX may have run in this thread without the shim (mx calls of its own)
        get("mlx")
    for backend in list(_INSTANCES.values()):
        backend.end_thread()


def available() -> list[str]:
    return sorted(set(_FACTORIES) | set(_LAZY_MODULES))


def get(name: str) -> Backend:
    """The backend called ``name`` ('numpy', 'jax', 'mlx' or a registered one)."""
    if name in _INSTANCES:
        return _INSTANCES[name]
    if name not in _FACTORIES and name in _LAZY_MODULES:
        importlib.import_module(_LAZY_MODULES[name])
    if name not in _FACTORIES:
        raise ValueError(f"unknown array backend {name!r}; available: {available()}")
    try:
        backend = _FACTORIES[name]()
    except ImportError as e:
        raise ImportError(f"array backend {name!r} needs a package that is not installed: {e}") from e
    _INSTANCES[name] = backend
    return backend


def _module_root(x: Any) -> str:
    return type(x).__module__.split(".", 1)[0]


_ROOT_TO_BACKEND = {"jax": "jax", "jaxlib": "jax", "mlx": "mlx", "numpy": "numpy"}


def namespace(*arrays: Any) -> Backend:
    """The backend owning ``arrays`` (python scalars and None are ignored; default numpy).

    Mixing backends is an error: a kernel must receive all its arrays from one library.
    """
    found: str | None = None
    for a in arrays:
        if a is None or isinstance(a, int | float | bool):
            continue
        root = _module_root(a)
        name = _ROOT_TO_BACKEND.get(root)
        if name is None:
            name = next((n for n, b in _INSTANCES.items() if b.owns(a)), None)
        if name is None:
            raise TypeError(f"no shim backend for arrays of type {type(a).__module__}.{type(a).__name__}")
        if found is not None and name != found:
            raise TypeError(f"arrays from two backends passed together: {found} and {name}")
        found = name
    return get(found or "numpy")
