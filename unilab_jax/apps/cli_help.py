"""``--help`` of the experiment scripts: the run's flags (those this script reads), then the algorithm's and the
task's config fields with their values for this experiment (the recipe's where it overrides the default), each
with a one-line doc, read from the comment beside (or above) the field in its dataclass.

``apps/cli.py``'s ``launch`` prints it and exits 0 on ``--help`` / ``-h`` / ``--helpshort``; ``--helpfull`` stays
absl's (every flag, absl's own too).
"""

from __future__ import annotations

import dataclasses
import inspect
import re
import sys
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from absl import flags

HELP_ARGS = ("--help", "-h", "--helpshort", "-help", "-?")
_FIELD = re.compile(r"^    (\w+)\s*:[^=]*(?:=.*)?$")
# The fields whose meaning no comment in their dataclass gives (the common names of the algorithms' configs).
COMMON_DOCS = {
    "actor_hidden": "hidden layer sizes of the policy network", "critic_hidden": "hidden layer sizes of the critic",
    "activation": "hidden-layer activation", "init_log_std": "initial log standard deviation of the policy",
    "learning_rate": "optimizer step size", "actor_learning_rate": "the actor's optimizer step size",
    "critic_learning_rate": "the critics' optimizer step size",
    "alpha_learning_rate": "the temperature's optimizer step size", "max_grad_norm": "gradient clipping norm",
    "num_epochs": "passes over each batch", "num_minibatches": "minibatches per epoch", "gamma": "discount factor",
    "lam": "GAE lambda", "clip_eps": "PPO ratio clipping", "vf_coef": "value loss coefficient",
    "ent_coef": "entropy bonus coefficient", "normalize_advantages": "standardise advantages per minibatch",
    "normalize_obs": "running mean/std observation normalisation", "obs_clip": "clip of normalised observations",
    "batch_size": "transitions per gradient step", "tau": "Polyak rate of the target networks",
    "replay_capacity": "replay transitions kept (over all workers)", "init_alpha": "initial entropy temperature",
    "weight_decay": "AdamW weight decay", "ctrl_dt": "control period (s)", "sim_dt": "physics step (s)",
    "episode_length": "control steps before truncation", "seed": "random seed",
    "utd": "gradient steps per env step (the update-to-data ratio)",
    "updates_per_call": "gradient steps per learner call",
    "learning_starts": "transitions in the replay buffer before the first gradient step",
    "publish_every": "gradient steps between weight publications to the workers",
    "kp": "PD position gain", "kd": "PD damping gain", "action_scale": "joint target offset per unit action",
    "num_atoms": "atoms of the distributional (C51) critic", "v_min": "lower end of the C51 critic's return support",
    "v_max": "upper end of the C51 critic's return support", "use_cdq": "clipped double Q (the min of two critics)",
    "critic_layer_norm": "LayerNorm in the critics", "compute_dtype": "the learner's compute dtype",
    "autotune_alpha": "learn the entropy temperature", "feature_dim": "image encoder output features",
    "image_pad": "random-shift augmentation padding of images (pixels)",
    "encoder_strides": "strides of the image encoder's convolutions", "solver_iterations": "MuJoCo solver iterations",
    "ls_iterations": "MuJoCo line-search iterations", "explore_std": "exploration noise standard deviation",
}


def field_docs(cls: type) -> dict[str, str]:
    """field name -> its comment (beside the field, else the comment block above it) in ``cls`` or a base class."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        try:
            lines = inspect.getsource(klass).splitlines()
        except (OSError, TypeError):
            continue
        above: list[str] = []
        group = ""  # a short comment above a run of fields heads the group ("# Reward", "# Domain randomisation")
        for line in lines:
            text = line.strip()
            if text.startswith("#") and line.startswith("    #"):
                above.append(text.lstrip("#").strip())
                continue
            match = _FIELD.match(line.split("  # ")[0])
            if match:
                name = match.group(1)
                beside = line.split("  # ", 1)[1].strip() if "  # " in line else ""
                header = " ".join(above)
                if header and len(header.split()) <= 8:
                    group, header = header.rstrip(":."), ""
                doc = beside or header or (f"{COMMON_DOCS.get(name, name.replace('_', ' '))} ({group})"
                                           if group else "")
                if doc:
                    docs[name] = doc
            elif not text:
                group = ""
            above = []
    return docs


def _one_line(text: str, width: int = 110, first_sentence: bool = True) -> str:
    text = " ".join(text.split())
    if first_sentence:
        text = re.split(r"(?<=\.)\s", text, maxsplit=1)[0].rstrip(".")
    return text if len(text) <= width else text[: width - 3].rstrip() + "..."


def _doc(name: str, docs: Mapping[str, str]) -> str:
    if name in docs:
        return _one_line(docs[name])
    if name.startswith("dr_"):
        return f"domain randomisation: {name.removeprefix('dr_').replace('_', ' ')}"
    if name.startswith("scale_"):
        return f"reward scale of the {name.removeprefix('scale_')} term"
    return COMMON_DOCS.get(name, name.replace("_", " "))


def config_lines(title: str, config: Any, overridden: Iterable[str] = (), flag: str = "--config") -> list[str]:
    """One line per field of the dataclass ``config``: ``name = value  doc`` (``[recipe]`` where the experiment
    sets it, with the default it replaces)."""
    default = type(config)() if _constructible(type(config)) else None
    docs, overridden = field_docs(type(config)), set(overridden)
    lines = [f"{title} (override with {flag} key=value):"]
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        mark = ""
        if field.name in overridden:
            mark = " [recipe" + (f"; default {getattr(default, field.name)!r}]" if default is not None else "]")
        lines.append(f"  {field.name} = {value!r}{mark}\n      {_doc(field.name, docs)}")
    return lines


def _constructible(cls: type) -> bool:
    try:
        cls()
    except Exception:
        return False
    return True


def exit_on_help(make_text: Any) -> None:
    """Prints ``make_text()`` and exits 0 when the command line asks for help (before absl parses it)."""
    if any(arg in HELP_ARGS for arg in sys.argv[1:]):
        sys.stdout.write(make_text())
        sys.stdout.flush()
        sys.exit(0)


def main_doc() -> str:
    return getattr(sys.modules.get("__main__"), "__doc__", None) or ""


def flag_lines(title: str, names: Sequence[str], defaults: Mapping[str, Any] | None = None) -> list[str]:
    """``--name (default: ...)`` and its help, one per flag; ``defaults``: this experiment's where the flag's own is
    a placeholder (``--total_steps``: the experiment's)."""
    lines, defaults = [f"{title}:"], defaults or {}
    for name in names:
        flag = flags.FLAGS[name]
        value = defaults.get(name, flag.default)
        if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10_000:
            shown = f"{value:_}"
        elif isinstance(value, bool):
            shown = str(value).lower()
        else:
            shown = str(value)
        default = "" if value in (None, []) else f" (default: {shown})"
        lines.append(f"  --{name}{default}\n      {_one_line(flag.help, 240, first_sentence=False)}")
    return lines


def flags_of(module_name: str) -> list[str]:
    """The flags ``module_name`` defines, in definition order."""
    return [f.name for f in flags.FLAGS.flags_by_module_dict().get(module_name, [])]


def script_flags() -> list[str]:
    """Flags defined by the script being run (``__main__``: absl files them under ``sys.argv[0]``)."""
    return flags_of(sys.argv[0])


def requested_task(default: str) -> str:
    """``--task`` as given on the command line (help runs before absl parses it), else ``default``."""
    args = sys.argv[1:]
    for i, arg in enumerate(args):
        if arg.startswith("--task="):
            return arg.split("=", 1)[1]
        if arg == "--task" and i + 1 < len(args):
            return args[i + 1]
    return default


def algorithm_lines(algo: str, recipe: Mapping[str, Any], title: str | None = None,
                    flag: str = "--config") -> list[str]:
    from unilab_jax import algos
    from unilab_jax.config import apply_overrides

    module = algos.get(algo)
    config = apply_overrides(module.Config(), dict(recipe))
    return config_lines(title or f"algorithm {algo} ({type(config).__name__})", config, recipe, flag)


def task_lines(task: str, task_recipe: Mapping[str, Any]) -> list[str]:
    import tasks
    from unilab_jax.config import apply_overrides

    try:
        config = apply_overrides(tasks.default_config(task), dict(task_recipe))
    except Exception as e:  # a gym:ENV_ID whose environment cannot be made here: say so, list the rest
        return [f"task {task}: its config cannot be read here ({e})"]
    return config_lines(f"task {task} ({type(config).__name__})", config, task_recipe, "--task_config")


def text(doc: str | None, sections: Sequence[list[str]]) -> str:
    """The whole help: the script's docstring, then each section."""
    parts = [(doc or "").strip()] + ["\n".join(section) for section in sections if section]
    parts.append("--helpfull lists every flag, absl's own included.")
    return "\n\n".join(p for p in parts if p) + "\n"
