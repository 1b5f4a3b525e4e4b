"""SAC Flow learns cart-pole balance through the real runtime (2 worker processes, the Trainer's replay loop,
the JAX learner), with sac_cartpole.py's recipe and a 2-step flow.

Measured (2-core dev VM, 450k env steps, ~173 updates of 32 gradient steps, 11-23 s wall; a random policy
scores ~35 of 200). Evaluations at 100k, 200k, 300k, 400k and the final one, 8 runs over seeds 0-3:
  [158 189 162 128 200] [165 197 198 140 124] [172 197 138 188 199] [196 198 163 188 200]
  [176 188 196 188 199] [146 198 199 196 195] [165 195 180 109 181] [180 198 200 199 200]
The policy is good by 200k in every run but dips now and then (109-140 in 5 of the 32 later evaluations;
a fresh-clone CI run ended on 129), and more under load: a fresh-clone CI run with three other jobs on the
2 cores (load 8) evaluated [181 181 96 118 163]. A single evaluation is no threshold: the test asserts the
best evaluation (lowest seen 181) and the mean of the evaluations from 200k on (lowest seen 139; 165-199
on an idle VM), both far above a random policy's 35. The evaluations run in their own process
(``eval_process="on"``, the path of a learner on an accelerator), so this run also checks that path end to end.

Budget 450k -> 300k (later session): evaluations at 100k, 200k and the final one at 300k. In the runs above
the first three evaluations give a best of >= 181 and a mean from 200k on of >= 139 (167 on an idle VM);
three runs at 300k (seeds 0-2): [169 200 187] [160 160 199] [165 194 197], best >= 187, mean from 200k >= 179.
Thresholds unchanged.
"""

import importlib.util
import json
import os

from unilab_jax import algos
from unilab_jax.config import apply_overrides
from unilab_jax.training.trainer import RunConfig, Trainer

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_sacflow_learns_cartpole(tmp_path):
    spec = importlib.util.spec_from_file_location("sac_cartpole", os.path.join(ROOT, "experiments", "sac_cartpole.py"))
    recipe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(recipe)
    module = algos.get("sacflow")
    config = apply_overrides(module.Config(), {**recipe.RECIPE, "flow_steps": 2})
    run = RunConfig(algo="sacflow", task="cartpole_balance", num_workers=2, envs_per_worker=16, total_steps=300_000,
                    seed=0, logdir=str(tmp_path / "run"), eval_envs=16, eval_every=100_000, eval_process="on")
    summary = Trainer(run, module, config, {}).train()
    rows = [json.loads(line) for line in open(os.path.join(summary["logdir"], "metrics.jsonl"))]
    assert summary["updates"] > 100 and not summary["interrupted"]
    assert all("loss/entropy" in r for r in rows if "loss/critic_loss" in r)
    evals = [(r["step"], r["eval/return"]) for r in rows if "eval/return" in r]
    assert len(evals) >= 3, evals
    later = [ret for step, ret in evals if step >= 200_000]
    assert max(ret for _, ret in evals) >= 165.0, evals
    assert sum(later) / len(later) >= 100.0, evals
