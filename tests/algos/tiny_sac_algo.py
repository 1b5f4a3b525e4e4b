"""A SAC variant declared outside the package, as a newcomer would add one (``test_contract.py`` registers it):
SAC whose actor maximises the critics' mean (``actor_q="mean"``) or their minimum. Adding an off-policy
algorithm takes this declaration and one ``algos.register`` call; its kernels here are SAC's."""

from __future__ import annotations

import dataclasses
from typing import Any

from unilab_jax.algos.offpolicy import sac
from unilab_jax.lazy import learner_maker

SYNC = "async"
BUFFER = "replay"


@dataclasses.dataclass(frozen=True)
class MeanQSACConfig(sac.SACConfig):
    actor_q: str = "mean"  # what the actor maximises: the critics' "mean" or their "min"

    def problems(self) -> list[str]:
        problems = super().problems()
        if self.actor_q not in ("mean", "min"):
            problems.append(f"actor_q must be 'mean' or 'min', got {self.actor_q!r}")
        return problems


Config = MeanQSACConfig
make_learner = learner_maker(__name__)
extras, act, init_params = sac.extras, sac.act, sac.init_params
critic_loss, temperature_loss = sac.critic_loss, sac.temperature_loss


def actor_loss(actor: Any, critic: Any, log_alpha: Any, norms: sac.Norms, mb: dict, eps: Any,
               config: MeanQSACConfig) -> tuple[Any, tuple]:
    return sac.soft_actor_loss(actor, critic, log_alpha, norms, mb, eps, sac.scalar_q, use_min=config.actor_q == "min")
