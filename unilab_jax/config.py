"""Frozen config dataclasses with generic, checked overrides.

Every algorithm has one frozen dataclass config and every task a ``default_config()``. Overrides come
as ``{"key": value}`` or ``["key=value", ...]`` strings (from the ``--config`` flag); unknown keys
are rejected with the list of valid ones, values are converted to the field's declared type, non-finite
numbers (``1e999``, ``nan``, ``inf``) are refused for every field, and the config's own validation
(its ``__post_init__``) failing is a :class:`ConfigError` too: the CLIs turn every one into exit 2.
"""

from __future__ import annotations

import ast
import dataclasses
import math
import typing
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

C = TypeVar("C")


class ConfigError(ValueError):
    """A bad override: unknown key, a value of the wrong type, a non-finite number, or values the config's
    own validation refuses."""


_NON_FINITE = ("nan", "+nan", "-nan", "inf", "+inf", "-inf", "infinity", "+infinity", "-infinity")


def _check_finite(name: str, value: Any) -> None:
    """Every float in ``value`` (tuples, lists and dicts searched) must be finite."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"config key {name!r}: must be a finite number, got {value!r}")
    if isinstance(value, list | tuple):
        for v in value:
            _check_finite(name, v)
    elif isinstance(value, dict):
        for v in value.values():
            _check_finite(name, v)


def _convert(name: str, value: Any, typ: Any) -> Any:
    origin = typing.get_origin(typ)
    if isinstance(value, str) and typ is not str:
        if value.strip().lower() in _NON_FINITE:
            raise ConfigError(f"config key {name!r}: must be a finite number, got {value!r}")
        try:
            value = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            if typ in (bool,) and value.lower() in ("true", "false"):
                value = value.lower() == "true"
            elif origin is typing.Union or typ is Any:
                pass
            else:
                raise ConfigError(f"config key {name!r}: cannot parse {value!r} as {typ}") from None
    if typ is float and isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    if typ is int and isinstance(value, bool):
        raise ConfigError(f"config key {name!r}: expected int, got bool {value!r}")
    if typ in (int, float, bool, str) and not isinstance(value, typ):
        raise ConfigError(f"config key {name!r}: expected {typ.__name__}, got {value!r}")
    if origin is tuple and isinstance(value, list | tuple):
        args = typing.get_args(typ)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(name, v, args[0]) for v in value)
        if len(args) != len(value):
            raise ConfigError(f"config key {name!r}: expected {len(args)} values, got {value!r}")
        return tuple(_convert(name, v, a) for v, a in zip(value, args))
    return value


def parse_overrides(items: Iterable[str] | Mapping[str, Any] | None) -> dict[str, Any]:
    """``["a=1", "b=(2, 3)"]`` -> ``{"a": "1", "b": "(2, 3)"}`` (values converted later)."""
    if items is None:
        return {}
    if isinstance(items, Mapping):
        return dict(items)
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"config override {item!r} is not of the form key=value")
        k, v = item.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def apply_overrides(config: C, overrides: Mapping[str, Any] | Iterable[str] | None) -> C:
    """A copy of the frozen dataclass ``config`` with ``overrides`` applied (checked, typed)."""
    overrides = parse_overrides(overrides)
    if not overrides:
        return config
    hints = typing.get_type_hints(type(config))
    fields = {f.name for f in dataclasses.fields(config)}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise ConfigError(
            f"unknown config key(s) {unknown} for {type(config).__name__}; valid keys: {sorted(fields)}"
        )
    typed = {k: _convert(k, v, hints[k]) for k, v in overrides.items()}
    for k, v in typed.items():
        _check_finite(k, v)
    try:  # the config's own checks (its __post_init__)
        return dataclasses.replace(config, **typed)
    except (ValueError, TypeError) as e:
        if isinstance(e, ConfigError):
            raise
        raise ConfigError(str(e)) from e


def as_dict(config: Any) -> dict[str, Any]:
    return dataclasses.asdict(config)


class SelfChecking:
    """Base of a config dataclass that validates its own fields: ``problems()`` lists what is wrong (a subclass
    appends its own fields' problems to its base's), and ``__post_init__`` raises one ``ValueError`` naming the
    class and every problem, so a bad value is refused before any worker starts."""

    def __post_init__(self) -> None:
        problems = self.problems()
        if problems:
            raise ValueError(f"{type(self).__name__}: " + "; ".join(problems))

    def problems(self) -> list[str]:
        return []


def hidden_size_problems(actor_hidden: tuple[int, ...], critic_hidden: tuple[int, ...]) -> list[str]:
    """The problem of non-positive hidden layer sizes (empty when every size is at least 1)."""
    if all(n >= 1 for n in (*actor_hidden, *critic_hidden)):
        return []
    return [f"hidden layer sizes must be positive (actor_hidden={actor_hidden}, critic_hidden={critic_hidden})"]
