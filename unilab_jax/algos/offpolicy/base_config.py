"""``OffPolicyConfig``: the fields every off-policy algorithm configures, and their validation.

Each config class of the family validates its own fields: it extends :meth:`OffPolicyConfig.problems` with its
fields' problems, and ``__post_init__`` raises one ``ValueError`` naming the class and every problem found
(``SACConfig``: the temperature and the image encoder; ``CategoricalSACConfig``: the C51 support;
``TD3Config``: the policy delay; ``RLPDConfig``, ``SACFlowConfig``: theirs).
"""

from __future__ import annotations

import dataclasses

from unilab_jax.config import SelfChecking, hidden_size_problems


@dataclasses.dataclass(frozen=True)
class OffPolicyConfig(SelfChecking):
    """What every off-policy algorithm of this family configures (defaults: SAC's).

    Read by the training loop (``unilab_jax/training``; ``algos.contract.ReplayLoopConfig``), not by a learner's
    update: ``utd`` gradient steps per collected transition; ``replay_capacity`` transitions in all (split over
    workers); ``learning_starts`` transitions collected before the first update; ``publish_every`` gradient
    steps between weight publications; ``horizon`` control steps per worker chunk (the runtime's unit; the
    trainer and the CLI read it). Read by both: ``batch_size`` and ``updates_per_call`` (U) gradient steps
    scanned inside one jitted ``update`` (the batch is ``[U, batch_size, ...]``). The rest is the learner's.
    ``compute_dtype``: the JAX learners' matrix multiplies -- "float32", "bfloat16" (bf16 operands,
    float32 accumulation, results, master weights, norms, softmax, C51 projection, log-probs, losses and
    optimizer: ``unilab_jax.xp``'s ``compute_dtype``) or "auto" (``learner_common.AUTO_COMPUTE_DTYPE``
    per backend: float32 on CPU). The MLX learners compute in float32 and refuse "bfloat16".
    ``ln_forward`` / ``ln_backward``: under bf16, the forward / backward pass of the critics' LayerNorm + ReLU
    layers -- "xla" (the XLA programs of ``mixed_precision._ln_fwd`` / ``_ln_bwd``), "pallas" (one fused Pallas
    kernel per layer and pass, ``unilab_jax.pallas_kernels``; for one device: XLA's SPMD partitioner does not
    split a Pallas call, so ``training.sharding`` refuses them on several devices) or "auto" (the default: "pallas"
    on one NVIDIA GPU, "xla" elsewhere; ``learner_common.resolve_ln_kernels``). The float32 program and the MLX
    learners ignore them. ``flat_optimizer``: the actor's and critics' optimizers over one flat vector of their
    parameters (``learner_common.make_optimizer``; the same arithmetic in fewer kernels); the MLX learners refuse it.
    """

    actor_hidden: tuple[int, ...] = (256, 256)
    critic_hidden: tuple[int, ...] = (256, 256)
    actor_learning_rate: float = 3e-4
    critic_learning_rate: float = 3e-4
    batch_size: int = 512
    utd: float = 1.0
    updates_per_call: int = 8
    replay_capacity: int = 1_000_000
    learning_starts: int = 5_000
    publish_every: int = 8
    horizon: int = 32  # env steps per worker chunk (bookkeeping only: async workers poll weights every step)
    gamma: float = 0.99
    tau: float = 0.005
    normalize_obs: bool = True
    max_grad_norm: float = 0.0  # 0 disables gradient clipping
    weight_decay: float = 0.0  # decoupled (AdamW) when > 0
    compute_dtype: str = "auto"
    ln_forward: str = "auto"  # bf16 LayerNorm + ReLU forward: "auto", "xla" or "pallas" (one fused kernel per layer)
    ln_backward: str = "auto"  # bf16 LayerNorm + ReLU backward: "auto", "xla" or "pallas" (one fused kernel per layer)
    flat_optimizer: bool = False  # the actor's and critics' Adam over one flat parameter vector (JAX only)

    def problems(self) -> list[str]:
        """This class's fields' problems (empty when valid); a subclass appends its own fields' to its base's."""
        problems = hidden_size_problems(self.actor_hidden, self.critic_hidden)
        if self.batch_size <= 0 or self.updates_per_call <= 0 or self.publish_every <= 0:
            problems.append("batch_size, updates_per_call and publish_every must be positive")
        if self.utd <= 0 or self.replay_capacity <= 0 or self.learning_starts < 0:
            problems.append("utd and replay_capacity must be positive, learning_starts >= 0")
        if not 0.0 <= self.gamma <= 1.0 or not 0.0 < self.tau <= 1.0:
            problems.append(f"need 0 <= gamma <= 1 and 0 < tau <= 1 (gamma={self.gamma}, tau={self.tau})")
        if self.compute_dtype not in ("auto", "float32", "bfloat16"):
            problems.append(f"compute_dtype must be 'auto', 'float32' or 'bfloat16', got {self.compute_dtype!r}")
        for name in ("ln_forward", "ln_backward"):
            if getattr(self, name) not in ("auto", "xla", "pallas"):
                problems.append(f"{name} must be 'auto', 'xla' or 'pallas', got {getattr(self, name)!r}")
        return problems
