"""Optimizers for MLX with optax semantics, as pure functions over explicit state pytrees.

Every optimizer is a :class:`GradientTransformation` ``(init, update)`` exactly as in optax::

    opt = optim.chain(optim.clip_by_global_norm(1.0), optim.adam(3e-4))
    opt_state = opt.init(params)
    updates, opt_state = opt.update(grads, opt_state, params)
    params = optim.apply_updates(params, updates)

Optimizer states are plain pytrees: dicts of ``mx.array`` (step counters are int32 scalars),
tuples for :func:`chain`, ``{}`` for stateless transforms and ``()`` for leaves hidden by a mask,
so ``xp.tree_map``, ``mlx.utils.tree_map``/``tree_flatten`` and ``mx.compile`` all traverse them.
Nothing is mutated in place, so a whole training state composes with ``mx.compile``::

    state = {"params": params, "opt": opt.init(params)}

    @partial(mx.compile, inputs=state, outputs=state)
    def step(batch):
        loss, grads = mx.value_and_grad(loss_fn)(state["params"], batch)
        updates, state["opt"] = opt.update(grads, state["opt"], state["params"])
        state["params"] = optim.apply_updates(state["params"], updates)
        return loss

    mx.eval(step(batch), state)   # one eval per step

Hyperparameters that change during training (a KL-adaptive PPO learning rate) live in the state
through :func:`inject_hyperparams`, as in optax::

    opt = optim.inject_hyperparams(optim.adam)(learning_rate=1e-3)
    opt_state["hyperparams"]["learning_rate"] = mx.array(5e-4)     # or set_hyperparams(...)

The numbers follow optax 0.2.x operation for operation (same formulas, same order, float32),
so MLX and optax agree to float32 rounding; ``tests/mlx/test_optim.py`` checks this.
This module imports mlx and numpy only (never jax or optax).
"""

from __future__ import annotations

import functools
import inspect
import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any, NamedTuple

import mlx.core as mx
import numpy as np

from unilab_jax.xp import tree_leaves, tree_map

__all__ = [
    "GradientTransformation", "Schedule", "ScalarOrSchedule", "MASKED",
    "apply_updates", "global_norm", "safe_increment",
    "identity", "chain", "masked", "scale", "scale_by_schedule", "scale_by_learning_rate",
    "clip_by_global_norm", "trace", "scale_by_adam", "add_decayed_weights",
    "sgd", "adam", "adamw",
    "inject_hyperparams", "set_hyperparams", "get_hyperparams",
    "constant_schedule", "polynomial_schedule", "linear_schedule", "cosine_decay_schedule",
    "warmup_cosine_decay_schedule", "join_schedules",
]

Params = Any
Updates = Any
OptState = Any
Schedule = Callable[[Any], Any]
ScalarOrSchedule = float | mx.array | Schedule

_INT32_MAX = 2**31 - 1
MASKED: tuple = ()  # stands for a leaf or subtree hidden by `masked` (optax's MaskedNode)


class GradientTransformation(NamedTuple):
    """``init(params) -> state``; ``update(updates, state, params=None) -> (updates, state)``."""

    init: Callable[[Params], OptState]
    update: Callable[..., tuple[Updates, OptState]]


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------
def _zero_count() -> mx.array:
    return mx.array(0, dtype=mx.int32)


def safe_increment(count: mx.array) -> mx.array:
    """``count + 1``, saturating at the int32 maximum instead of wrapping (optax.safe_increment)."""
    return mx.where(count < _INT32_MAX, count + 1, count)


def _zeros_like(tree: Any, dtype: Any = None) -> Any:
    if dtype is None:
        return tree_map(mx.zeros_like, tree)
    return tree_map(lambda p: mx.zeros(p.shape, dtype=dtype), tree)


def _cast(tree: Any, dtype: Any) -> Any:
    return tree if dtype is None else tree_map(lambda t: t.astype(dtype), tree)


def _as_dtype(x: Any, dtype: Any) -> mx.array:
    return x.astype(dtype) if isinstance(x, mx.array) else mx.array(x, dtype=dtype)


def _as_count(count: Any) -> mx.array:
    return count if isinstance(count, mx.array) else mx.array(count, dtype=mx.int32)


def global_norm(tree: Any) -> mx.array:
    """sqrt of the sum of squares of every leaf (optax.tree.norm, leaves summed in tree order)."""
    sq = mx.array(0.0)
    for leaf in tree_leaves(tree):
        sq = sq + mx.sum(mx.square(leaf))
    return mx.sqrt(sq)


def apply_updates(params: Params, updates: Updates) -> Params:
    """``params + updates`` leaf by leaf, keeping each parameter's dtype (optax.apply_updates)."""
    return tree_map(lambda p, u: p if u is None else (p + u).astype(p.dtype), params, updates)


# ---------------------------------------------------------------------------------------------
# combinators
# ---------------------------------------------------------------------------------------------
def identity() -> GradientTransformation:
    """Passes updates through; state ``{}``."""
    return GradientTransformation(lambda params: {}, lambda updates, state, params=None: (updates, state))


def chain(*transforms: GradientTransformation) -> GradientTransformation:
    """Applies ``transforms`` in order; the state is the tuple of their states (optax.chain)."""

    def init(params: Params) -> tuple:
        return tuple(t.init(params) for t in transforms)

    def update(updates: Updates, state: tuple, params: Params = None) -> tuple[Updates, tuple]:
        if len(state) != len(transforms):
            raise ValueError(f"chain of {len(transforms)} transforms got a state of length {len(state)}; "
                             "was it made by this chain's init?")
        new_state = []
        for t, s in zip(transforms, state):
            updates, s = t.update(updates, s, params)
            new_state.append(s)
        return updates, tuple(new_state)

    return GradientTransformation(init, update)


def masked(inner: GradientTransformation, mask: Any) -> GradientTransformation:
    """Applies ``inner`` only where ``mask`` is True; elsewhere updates pass through unchanged.

    ``mask`` is a pytree of Python bools with the structure of the params (or a prefix of it: a
    bool for a whole subtree), or a callable returning one from the params / updates. Hidden leaves
    (or subtrees) reach ``inner`` as :data:`MASKED`, an empty tuple, so its state holds ``()`` there
    (optax's ``MaskedNode``): a node without leaves for every tree utility (``xp.tree_map``,
    ``mlx.utils``, ``mx.compile``). State: ``{"inner_state": ...}``.
    """

    def mask_tree(tree: Any) -> Any:
        return mask(tree) if callable(mask) else mask

    def hide(tree: Any, m: Any) -> Any:
        return tree_map(lambda keep, x: x if keep else MASKED, m, tree)

    def init(params: Params) -> dict:
        return {"inner_state": inner.init(hide(params, mask_tree(params)))}

    def update(updates: Updates, state: dict, params: Params = None) -> tuple[Updates, dict]:
        m = mask_tree(updates)
        new_u, inner_state = inner.update(hide(updates, m), state["inner_state"],
                                          None if params is None else hide(params, m))
        merged = tree_map(lambda keep, new, old: new if keep else old, m, new_u, updates)
        return merged, {"inner_state": inner_state}

    return GradientTransformation(init, update)


# ---------------------------------------------------------------------------------------------
# scaling
# ---------------------------------------------------------------------------------------------
def scale(step_size: float | mx.array) -> GradientTransformation:
    """Multiplies updates by ``step_size``; state ``{}``."""

    def update(updates: Updates, state: dict, params: Params = None) -> tuple[Updates, dict]:
        return tree_map(lambda g: step_size * g, updates), state

    return GradientTransformation(lambda params: {}, update)


def scale_by_schedule(step_size_fn: Schedule) -> GradientTransformation:
    """Multiplies updates by ``step_size_fn(count)``; state ``{"count": int32}``."""

    def init(params: Params) -> dict:
        return {"count": _zero_count()}

    def update(updates: Updates, state: dict, params: Params = None) -> tuple[Updates, dict]:
        step_size = step_size_fn(state["count"])
        updates = tree_map(lambda g: _as_dtype(step_size, g.dtype) * g, updates)
        return updates, {"count": safe_increment(state["count"])}

    return GradientTransformation(init, update)


def scale_by_learning_rate(learning_rate: ScalarOrSchedule | None, *,
                           flip_sign: bool = True) -> GradientTransformation:
    """Scales by ``-learning_rate`` (a scalar, an ``mx.array`` or a schedule); None: identity."""
    if learning_rate is None:
        return identity()
    m = -1 if flip_sign else 1
    if callable(learning_rate):
        return scale_by_schedule(lambda count: m * learning_rate(count))
    return scale(m * learning_rate)


def clip_by_global_norm(max_norm: float | mx.array) -> GradientTransformation:
    """Rescales updates to global norm ``max_norm`` when their norm exceeds it; state ``{}``."""

    def update(updates: Updates, state: dict, params: Params = None) -> tuple[Updates, dict]:
        g_norm = global_norm(updates)
        trigger = g_norm < max_norm
        updates = tree_map(lambda t: mx.where(trigger, t, (t / g_norm.astype(t.dtype)) * max_norm), updates)
        return updates, state

    return GradientTransformation(lambda params: {}, update)


def trace(decay: float | mx.array, nesterov: bool = False,
          accumulator_dtype: Any = None) -> GradientTransformation:
    """Momentum: ``t <- g + decay * t``; state ``{"trace": like params}`` (optax.trace)."""

    def init(params: Params) -> dict:
        return {"trace": _zeros_like(params, accumulator_dtype)}

    def update(updates: Updates, state: dict, params: Params = None) -> tuple[Updates, dict]:
        f = lambda g, t: g + decay * t
        new_trace = tree_map(f, updates, state["trace"])
        updates = tree_map(f, updates, new_trace) if nesterov else new_trace
        return updates, {"trace": _cast(new_trace, accumulator_dtype)}

    return GradientTransformation(init, update)


def _update_moment(updates: Updates, moments: Any, decay: Any, order: int) -> Any:
    power = mx.square if order == 2 else (lambda g: g)
    return tree_map(lambda g, t: (1 - decay) * power(g) + decay * t, updates, moments)


def _bias_correction(moment: Any, decay: Any, count: mx.array) -> Any:
    correction = 1 - decay**count
    return tree_map(lambda t: t / correction.astype(t.dtype), moment)


def scale_by_adam(b1: float | mx.array = 0.9, b2: float | mx.array = 0.999, eps: float | mx.array = 1e-8,
                  eps_root: float | mx.array = 0.0, mu_dtype: Any = None, *,
                  nesterov: bool = False) -> GradientTransformation:
    """Adam's rescaling ``m_hat / (sqrt(v_hat + eps_root) + eps)`` (optax.scale_by_adam).

    State ``{"count": int32, "mu": like params, "nu": like params}``.
    """

    def init(params: Params) -> dict:
        return {"count": _zero_count(), "mu": _zeros_like(params, mu_dtype), "nu": _zeros_like(params)}

    def update(updates: Updates, state: dict, params: Params = None) -> tuple[Updates, dict]:
        mu = _update_moment(updates, state["mu"], b1, 1)
        nu = _update_moment(updates, state["nu"], b2, 2)
        count = safe_increment(state["count"])
        if nesterov:
            mu_hat = tree_map(lambda m, g: b1 * m + (1 - b1) * g,
                              _bias_correction(mu, b1, safe_increment(count)),
                              _bias_correction(updates, b1, count))
        else:
            mu_hat = _bias_correction(mu, b1, count)
        nu_hat = _bias_correction(nu, b2, count)
        updates = tree_map(lambda m, v: m / (mx.sqrt(v + eps_root) + eps), mu_hat, nu_hat)
        mu = _cast(mu, mu_dtype)
        nu = tree_map(lambda n, old: n.astype(old.dtype), nu, state["nu"])
        return updates, {"count": count, "mu": mu, "nu": nu}

    return GradientTransformation(init, update)


def add_decayed_weights(weight_decay: ScalarOrSchedule = 0.0, mask: Any = None) -> GradientTransformation:
    """``updates + weight_decay * params`` (decoupled weight decay), optionally masked.

    State ``{}``, or ``{"count": int32}`` when ``weight_decay`` is a schedule; wrapped in
    :func:`masked` when ``mask`` is given.
    """

    def init(params: Params) -> dict:
        return {"count": _zero_count()} if callable(weight_decay) else {}

    def update(updates: Updates, state: dict, params: Params = None) -> tuple[Updates, dict]:
        if params is None:
            raise ValueError("add_decayed_weights needs the params: call update(updates, state, params)")
        new_state = {"count": safe_increment(state["count"])} if callable(weight_decay) else state
        if isinstance(weight_decay, int | float) and weight_decay == 0.0:
            return updates, new_state
        s = weight_decay(state["count"]) if callable(weight_decay) else weight_decay
        return tree_map(lambda g, p: g + s * p, updates, params), new_state

    t = GradientTransformation(init, update)
    return t if mask is None else masked(t, mask)


# ---------------------------------------------------------------------------------------------
# optimizers (the same chains as optax, so states have the same layout)
# ---------------------------------------------------------------------------------------------
def sgd(learning_rate: ScalarOrSchedule, momentum: float | mx.array | None = None, nesterov: bool = False,
        accumulator_dtype: Any = None) -> GradientTransformation:
    """SGD with optional (Nesterov) momentum: ``chain(trace, scale_by_learning_rate)``."""
    first = identity() if momentum is None else trace(momentum, nesterov, accumulator_dtype)
    return chain(first, scale_by_learning_rate(learning_rate))


def adam(learning_rate: ScalarOrSchedule, b1: float | mx.array = 0.9, b2: float | mx.array = 0.999,
         eps: float | mx.array = 1e-8, eps_root: float | mx.array = 0.0, mu_dtype: Any = None, *,
         nesterov: bool = False) -> GradientTransformation:
    """Adam: ``chain(scale_by_adam, scale_by_learning_rate)``; state ``(adam_state, lr_state)``."""
    return chain(scale_by_adam(b1, b2, eps, eps_root, mu_dtype, nesterov=nesterov),
                 scale_by_learning_rate(learning_rate))


def adamw(learning_rate: ScalarOrSchedule, b1: float | mx.array = 0.9, b2: float | mx.array = 0.999,
          eps: float | mx.array = 1e-8, eps_root: float | mx.array = 0.0, mu_dtype: Any = None,
          weight_decay: ScalarOrSchedule = 1e-4, mask: Any = None, *,
          nesterov: bool = False) -> GradientTransformation:
    """AdamW as optax: ``-lr * (adam_update + weight_decay * params)``; ``mask`` selects decayed leaves.

    State ``(adam_state, decay_state, lr_state)``.
    """
    return chain(scale_by_adam(b1, b2, eps, eps_root, mu_dtype, nesterov=nesterov),
                 add_decayed_weights(weight_decay, mask),
                 scale_by_learning_rate(learning_rate))


# ---------------------------------------------------------------------------------------------
# injected hyperparameters
# ---------------------------------------------------------------------------------------------
_INJECT_KEYS = frozenset({"count", "hyperparams", "inner_state"})
_FLOAT_RANK = {mx.float16: 1, mx.bfloat16: 1, mx.float32: 2, mx.float64: 3}


def _highest_float_dtype(tree: Any) -> Any:
    """The widest floating dtype among the leaves (float32 if none; float16 + bfloat16 -> float32)."""
    found = {leaf.dtype for leaf in tree_leaves(tree)
             if isinstance(leaf, mx.array) and mx.issubdtype(leaf.dtype, mx.floating)}
    if not found:
        return mx.float32
    best = max(found, key=lambda d: _FLOAT_RANK.get(d, 2))
    if best in (mx.float16, mx.bfloat16) and len(found) > 1:
        return mx.float32
    return best


def _convert_hyperparam(x: Any, dtype: Any) -> Any:
    """Floats become ``dtype`` arrays, ints int32 arrays; anything else is left alone."""
    if isinstance(x, bool):
        return x
    if isinstance(x, np.ndarray | np.generic):
        x = mx.array(x)
    if isinstance(x, mx.array):
        return x.astype(dtype) if mx.issubdtype(x.dtype, mx.floating) else x
    if isinstance(x, float):
        return mx.array(x, dtype=dtype)
    if isinstance(x, int):
        return mx.array(x, dtype=mx.int32)
    return x


def inject_hyperparams(inner_factory: Callable[..., GradientTransformation],
                       static_args: str | Iterable[str] = (),
                       hyperparam_dtype: Any = None) -> Callable[..., GradientTransformation]:
    """Moves an optimizer's numeric hyperparameters into its state (optax.inject_hyperparams).

    ``inject_hyperparams(adam)(learning_rate=1e-3, b1=0.9)`` returns a transformation whose state is
    ``{"count": int32, "hyperparams": {"learning_rate": f32, "b1": f32, ...}, "inner_state": ...}``.
    Numeric arguments are stored as arrays and may be changed between (or inside compiled) steps by
    writing ``state["hyperparams"][name]``; callable arguments are schedules, evaluated at
    ``state["count"]`` on every update (writing them has no effect). Bools, ``None`` and the names in
    ``static_args`` (e.g. ``"mask"`` when the mask is a callable) are passed through unchanged.
    Hyperparameters are stored in ``hyperparam_dtype`` (default: the widest float dtype of the params,
    as optax; with bfloat16 params b2=0.999 then rounds to 1 and Adam divides 0 by 0, so pass
    ``hyperparam_dtype=mx.float32`` for low-precision params).
    """
    static = {static_args} if isinstance(static_args, str) else set(static_args)
    signature = inspect.signature(inner_factory)
    if not static.issubset(signature.parameters):
        raise ValueError(f"static_args {sorted(static)} must name parameters of {inner_factory.__name__}: "
                         f"{list(signature.parameters)}")

    @functools.wraps(inner_factory)
    def wrapped(*args: Any, **kwargs: Any) -> GradientTransformation:
        bound = signature.bind(*args, **kwargs)
        bound.apply_defaults()
        schedules: dict[str, Callable] = {}
        numeric: dict[str, Any] = {}
        other: dict[str, Any] = {}
        for name, value in bound.arguments.items():
            if name in static or isinstance(value, bool):
                other[name] = value
            elif callable(value):
                schedules[name] = value
            elif isinstance(value, int | float | mx.array | np.ndarray | np.generic):
                numeric[name] = value
            else:
                other[name] = value

        def dtype_of(params: Params) -> Any:
            return hyperparam_dtype if hyperparam_dtype is not None else _highest_float_dtype(params)

        def init(params: Params) -> dict:
            dtype = dtype_of(params)
            count = _zero_count()
            hparams = {k: _convert_hyperparam(v, dtype) for k, v in numeric.items()}
            hparams.update({k: _convert_hyperparam(f(count), dtype) for k, f in schedules.items()})
            return {"count": count, "hyperparams": hparams,
                    "inner_state": inner_factory(**other, **hparams).init(params)}

        def update(updates: Updates, state: dict, params: Params = None) -> tuple[Updates, dict]:
            dtype = dtype_of(params if params is not None else updates)
            hparams = {k: _convert_hyperparam(v, dtype) for k, v in state["hyperparams"].items()}
            hparams.update({k: _convert_hyperparam(f(state["count"]), dtype) for k, f in schedules.items()})
            inner = inner_factory(**other, **hparams)
            updates, inner_state = inner.update(updates, state["inner_state"], params)
            return updates, {"count": safe_increment(state["count"]), "hyperparams": hparams,
                             "inner_state": inner_state}

        return GradientTransformation(init, update)

    return wrapped


def _is_inject_state(x: Any) -> bool:
    return isinstance(x, dict) and x.keys() == _INJECT_KEYS and isinstance(x["hyperparams"], dict)


def set_hyperparams(opt_state: OptState, **values: Any) -> OptState:
    """A copy of ``opt_state`` with injected hyperparameters replaced, wherever they occur.

    Walks dicts, lists and tuples (so an :func:`inject_hyperparams` state nested in a :func:`chain`
    is found); each value is stored with the dtype of the entry it replaces, so the state keeps its
    structure and dtypes (no recompilation under ``mx.compile``). Arrays inside are shared, not
    copied. Raises ``KeyError`` if a name is not an injected hyperparameter anywhere.
    """
    found: set[str] = set()

    def walk(x: Any) -> Any:
        if _is_inject_state(x):
            hp = dict(x["hyperparams"])
            for k, v in values.items():
                if k in hp:
                    old = hp[k]
                    hp[k] = _as_dtype(v, old.dtype) if isinstance(old, mx.array) else v
                    found.add(k)
            return {"count": x["count"], "hyperparams": hp, "inner_state": walk(x["inner_state"])}
        if isinstance(x, dict):
            return {k: walk(v) for k, v in x.items()}
        if isinstance(x, list | tuple) and not hasattr(x, "_fields"):
            return type(x)(walk(v) for v in x)
        return x

    new_state = walk(opt_state)
    missing = set(values) - found
    if missing:
        raise KeyError(f"no injected hyperparameter(s) {sorted(missing)} in this optimizer state "
                       "(wrap the optimizer with inject_hyperparams)")
    return new_state


def get_hyperparams(opt_state: OptState) -> dict[str, Any]:
    """The injected hyperparameters of ``opt_state`` (outermost first wins on name clashes)."""
    out: dict[str, Any] = {}

    def walk(x: Any) -> None:
        if _is_inject_state(x):
            for k, v in x["hyperparams"].items():
                out.setdefault(k, v)
            walk(x["inner_state"])
        elif isinstance(x, dict):
            for v in x.values():
                walk(v)
        elif isinstance(x, list | tuple):
            for v in x:
                walk(v)

    walk(opt_state)
    return out


# ---------------------------------------------------------------------------------------------
# schedules: callables count -> value (count an int32 mx.array or a Python int)
# ---------------------------------------------------------------------------------------------
def constant_schedule(value: float | mx.array) -> Schedule:
    """Always ``value``."""
    return lambda count: value


def polynomial_schedule(init_value: float, end_value: float, power: float, transition_steps: int,
                        transition_begin: int = 0) -> Schedule:
    """``(init - end) * (1 - t / transition_steps) ** power + end`` with ``t`` clipped to [0, steps]."""
    if transition_steps <= 0:
        return lambda count: init_value
    transition_begin = max(int(transition_begin), 0)

    def schedule(count: Any) -> mx.array:
        count = mx.clip(_as_count(count) - transition_begin, 0, transition_steps)
        frac = 1 - count / transition_steps
        return (init_value - end_value) * (frac if power == 1 else frac**power) + end_value

    return schedule


def linear_schedule(init_value: float, end_value: float, transition_steps: int,
                    transition_begin: int = 0) -> Schedule:
    """Linear from ``init_value`` to ``end_value`` over ``transition_steps`` after ``transition_begin``."""
    return polynomial_schedule(init_value, end_value, 1, transition_steps, transition_begin)


def cosine_decay_schedule(init_value: float, decay_steps: int, alpha: float = 0.0,
                          exponent: float = 1.0) -> Schedule:
    """Cosine decay from ``init_value`` to ``alpha * init_value`` over ``decay_steps`` (optax).

    ``init * ((1 - alpha) * (0.5 * (1 + cos(pi * min(t, steps) / steps))) ** exponent + alpha)``.
    """
    if not decay_steps > 0:
        raise ValueError(f"cosine_decay_schedule needs positive decay_steps, got {decay_steps=}")
    decay_steps = float(decay_steps)

    def schedule(count: Any) -> mx.array:
        count = mx.minimum(_as_count(count), decay_steps)
        cosine = 0.5 * (1 + mx.cos(math.pi * count / decay_steps))
        decayed = (1 - alpha) * (cosine if exponent == 1 else cosine**exponent) + alpha
        return init_value * decayed

    return schedule


def join_schedules(schedules: Sequence[Schedule], boundaries: Sequence[int]) -> Schedule:
    """``schedules[i]`` from ``boundaries[i-1]`` on, each restarted at its boundary (optax)."""

    def schedule(step: Any) -> mx.array:
        step = _as_count(step)
        out = schedules[0](step)
        for boundary, s in zip(boundaries, schedules[1:]):
            out = mx.where(step < boundary, out, s(step - boundary))
        return out

    return schedule


def warmup_cosine_decay_schedule(init_value: float, peak_value: float, warmup_steps: int, decay_steps: int,
                                 end_value: float = 0.0, exponent: float = 1.0) -> Schedule:
    """Linear warm-up ``init -> peak`` over ``warmup_steps``, then cosine ``peak -> end``.

    The decay ends at step ``decay_steps``, which counts the warm-up (as in optax).
    """
    alpha = 0.0 if peak_value == 0.0 else end_value / peak_value
    return join_schedules(
        [linear_schedule(init_value, peak_value, warmup_steps),
         cosine_decay_schedule(peak_value, decay_steps - warmup_steps, alpha, exponent)],
        [warmup_steps])
