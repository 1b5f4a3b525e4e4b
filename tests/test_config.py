"""Generic config overrides: typed, checked, unknown keys rejected."""

import dataclasses

import pytest

from unilab_jax.config import ConfigError, apply_overrides


@dataclasses.dataclass(frozen=True)
class Cfg:
    lr: float = 1e-3
    epochs: int = 5
    hidden: tuple[int, ...] = (64, 64)
    pair: tuple[float, float] = (0.0, 1.0)
    norm: bool = True
    name: str = "x"


def test_string_overrides_are_typed():
    c = apply_overrides(Cfg(), ["lr=3e-4", "epochs=2", "hidden=(32, 16, 8)", "norm=False", "name=abc",
                                "pair=(1, 2)"])
    assert c == Cfg(lr=3e-4, epochs=2, hidden=(32, 16, 8), pair=(1.0, 2.0), norm=False, name="abc")
    assert isinstance(c.pair[0], float)


def test_unknown_key_lists_valid_keys():
    with pytest.raises(ConfigError, match=r"unknown config key\(s\) \['lrr'\].*valid keys"):
        apply_overrides(Cfg(), {"lrr": 1})


@pytest.mark.parametrize("bad", [["epochs=abc"], ["epochs=1.5"], ["norm=3"], ["pair=(1, 2, 3)"], ["lr"]])
def test_bad_values_rejected(bad):
    with pytest.raises(ConfigError):
        apply_overrides(Cfg(), bad)
