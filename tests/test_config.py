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


@pytest.mark.parametrize("bad", [["lr=1e999"], ["lr=-1e999"], ["lr=nan"], ["lr=inf"], ["lr=-Infinity"],
                                 ["pair=(0.0, 1e999)"], {"lr": float("nan")}, {"pair": (0.0, float("inf"))}])
def test_non_finite_values_rejected(bad):
    with pytest.raises(ConfigError, match="must be a finite number"):
        apply_overrides(Cfg(), bad)


@dataclasses.dataclass(frozen=True)
class Checked:
    gamma: float = 0.99

    def __post_init__(self):
        if not 0.0 <= self.gamma <= 1.0:
            raise ValueError(f"Checked: need 0 <= gamma <= 1, got {self.gamma}")


def test_the_configs_own_validation_is_a_config_error():
    with pytest.raises(ConfigError, match="need 0 <= gamma <= 1, got 2.5"):
        apply_overrides(Checked(), ["gamma=2.5"])


@pytest.mark.parametrize("algo,override,message", [
    ("ppo", "gamma=2.5", "PPOConfig: need 0 <= gamma <= 1"),
    ("ppo", "num_minibatches=0", "num_minibatches must be positive"),
    ("ppo", "actor_hidden=(64, -1)", "hidden layer sizes must be positive"),
    ("appo", "clip_eps=-0.2", "clip_eps and obs_clip must be positive"),
    ("sac", "batch_size=-5", "SACConfig: batch_size"),
    ("td3", "critic_hidden=(0,)", "hidden layer sizes must be positive"),
])
def test_algorithm_configs_refuse_bad_values(algo, override, message):
    from unilab_jax import algos

    with pytest.raises(ConfigError, match=message):
        apply_overrides(algos.get(algo).Config(), [override])
