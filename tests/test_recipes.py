"""Recipes list only what differs from the defaults (unilab_jax/recipes.py, which experiments/*.py run, and
bench/time_to_target.py's flags).

Each experiment script is run as ``__main__`` with its launcher (``run_experiment``, ``run_mjx_experiment``,
``run_robot_experiment``, ``run_hora``) replaced by a recorder, so what is checked is exactly what the script
passes. An entry written in a script's recipe is redundant when it equals, for every run that uses it, the
default it overrides: the algorithm's ``Config`` field, the task's ``default_config`` field, or the launcher's
own default (``default_total_steps`` ...). A shared recipe (``from ppo_go1 import RECIPE``) serves several
algorithms: an entry there stays while any of them needs it (e.g. a PPO value that is APPO's default).
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import inspect
import os
import runpy
import sys
from typing import Any

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXPERIMENTS = os.path.join(ROOT, "experiments")
RECIPES = "unilab_jax.recipes"  # where the recipe dicts are written (the scripts pass recipes.get(name).kwargs)
LAUNCHERS = {"run_experiment": "unilab_jax.apps.cli", "run_mjx_experiment": "unilab_jax.apps.mjx_cli",
             "run_robot_experiment": "unilab_jax.apps.robot_cli", "run_hora": "unilab_jax.apps.hora_cli"}
# the launchers' parameters that are recipes (checked key by key) rather than values with a default
RECIPE_PARAMS = {"recipe": "algo", "task_recipe": "task", "teacher_recipe": "hora_teacher",
                 "student_recipe": "hora_student"}
SCRIPTS = sorted(n for n in os.listdir(EXPERIMENTS) if n.endswith(".py")
                 and any(launcher in open(os.path.join(EXPERIMENTS, n)).read() for launcher in LAUNCHERS))


@pytest.fixture(scope="module")
def calls() -> dict[str, tuple[str, dict[str, Any], dict[str, Any], dict[str, Any]]]:
    """script -> (launcher, its arguments as passed, with the defaults filled in, the script's globals)."""
    out, modules = {}, set(sys.modules)
    sys.path.insert(0, EXPERIMENTS)
    try:
        for script in SCRIPTS:
            seen: list = []
            saved = {}
            for name, module_name in LAUNCHERS.items():
                module = importlib.import_module(module_name)
                saved[name] = (module, getattr(module, name))
                setattr(module, name, lambda *a, _name=name, _seen=seen, **kw: _seen.append((_name, a, kw)))
            try:
                ns = runpy.run_path(os.path.join(EXPERIMENTS, script), run_name="__main__")
            finally:
                for name, (module, fn) in saved.items():
                    setattr(module, name, fn)
            assert len(seen) == 1, f"{script}: expected one launcher call, got {seen}"
            name, args, kwargs = seen[0]
            bound = inspect.signature(saved[name][1]).bind(*args, **kwargs)
            given = dict(bound.arguments)
            bound.apply_defaults()
            out[script] = (name, given, dict(bound.arguments), ns)
        yield out  # the scripts' siblings stay importable while the tests read their recipes
    finally:
        sys.path.remove(EXPERIMENTS)
        for name in set(sys.modules) - modules:  # the scripts imported here (some bound a recorder as launcher)
            if os.path.dirname(getattr(sys.modules[name], "__file__", None) or "") == EXPERIMENTS:
                del sys.modules[name]


def _module(name: str) -> dict[str, Any]:
    return vars(importlib.import_module(name))


def _dicts(module: str) -> dict[str, tuple[str, Any]]:
    """Top-level names of an experiment module: ``("dict", entries)`` for a dict display (entries: ``(key, value
    expression)`` or ``(None, splatted name)``), ``("import", (module, name))`` for a name from a sibling script."""
    path = os.path.join(ROOT, *RECIPES.split(".")) + ".py" if module == RECIPES else os.path.join(EXPERIMENTS,
                                                                                                 module + ".py")
    tree = ast.parse(open(path).read())
    out: dict[str, tuple[str, Any]] = {}
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module and os.path.isfile(
                os.path.join(EXPERIMENTS, node.module + ".py")):
            for alias in node.names:
                out[alias.asname or alias.name] = ("import", (node.module, alias.name))
        elif isinstance(node, ast.ImportFrom) and node.module == RECIPES:
            for alias in node.names:
                out[alias.asname or alias.name] = ("import", (RECIPES, alias.name))
        elif isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            target = node.targets[0].id
            if isinstance(node.value, ast.Dict):
                entries = []
                for k, v in zip(node.value.keys, node.value.values):
                    assert k is None or isinstance(k, ast.Constant), f"{module}.{target}: constant keys only"
                    assert k is not None or isinstance(v, ast.Name), f"{module}.{target}: splat a plain name"
                    entries.append((None, v.id) if k is None else (k.value, v))
                out[target] = ("dict", entries)
            elif isinstance(node.value, ast.Name):
                out[target] = ("alias", node.value.id)
    return out


def _resolve(module: str, name: str, drop: tuple[str, str, str] | None = None) -> tuple[dict[str, Any], set]:
    """The dict ``module.name`` evaluated entry by entry, without the entry ``drop`` ((module, name, key)), and
    the entries written in experiments/ that make it up. A dict from outside experiments/ (e.g.
    ``unilab_jax.apps.robot_cli.MANIPULATION_RECIPE``) counts as one value: it is not the scripts' to trim."""
    kind, what = _dicts(module).get(name, ("external", None))
    if kind == "import":
        return _resolve(*what, drop)
    if kind == "alias":
        return _resolve(module, what, drop)
    if kind == "external":
        return dict(_module(module)[name]), set()
    out, entries = {}, set()
    for key, node in what:
        if key is None:
            values, inner = _resolve(module, node, drop)
            out.update(values)
            entries |= inner
        else:
            entries.add((module, name, key))
            if (module, name, key) != drop:
                out[key] = eval(compile(ast.Expression(node), module, "eval"), _module(module))
    return out, entries


def _global_name(ns: dict[str, Any], value: dict) -> tuple[str, str]:
    """(module, name) of the recipe dict ``value``: a top-level name of unilab_jax.recipes, else of the script."""
    for module, names in ((RECIPES, _module(RECIPES)), (None, ns)):
        found = [k for k, v in names.items() if v is value and not k.startswith("_")]
        if found:
            return module, found[0]
    raise AssertionError("a recipe passed to a launcher must be a top-level name of unilab_jax.recipes or the script")


def _defaults(launcher: str, arguments: dict[str, Any], param: str) -> Any:
    """The config a recipe parameter's entries override (a frozen dataclass)."""
    import tasks
    from unilab_jax import algos
    from unilab_jax.config import apply_overrides

    if param == "task_recipe":
        base = tasks.default_config(arguments["task"])
        if launcher == "run_robot_experiment":  # the robot CLI's own task settings lie under the script's
            from unilab_jax.apps import robot_cli

            base = apply_overrides(base, {**robot_cli.ROBOT_TASK, **robot_cli.OBSERVATIONS[arguments["observation"]]})
        return base
    algo = arguments["algo"] if param == "recipe" else RECIPE_PARAMS[param]
    return algos.get(algo).Config()


def test_every_script_is_checked(calls):
    assert {"fastsac_go1.py", "ppo_go1.py", "hora_go1.py", "fastsac_go1_mjx.py", "sac_franka_pick.py"} <= set(calls)


def test_no_recipe_entry_equals_the_default_it_overrides(calls):
    """Dropping any entry written in experiments/ changes the config of at least one run that uses it (unknown
    keys fail ``apply_overrides``)."""
    from unilab_jax.config import apply_overrides

    needed: dict[tuple[str, str, str], bool] = {}  # (module, dict name, key) -> some run's config needs it
    for script, (launcher, given, arguments, ns) in calls.items():
        for param in RECIPE_PARAMS:
            recipe = given.get(param)
            if not recipe:
                continue
            module, name = _global_name(ns, recipe)
            module = module or script[:-3]
            values, entries = _resolve(module, name)
            assert values == recipe, f"{script} {name}: read back differently"
            defaults = _defaults(launcher, arguments, param)
            config = apply_overrides(defaults, recipe)
            for entry in entries:
                without = apply_overrides(defaults, _resolve(module, name, drop=entry)[0])
                needed[entry] = needed.get(entry, False) or without != config
    redundant = sorted(f"{module}.py {name}[{key!r}]" for (module, name, key), need in needed.items()
                       if not need)
    assert not redundant, f"recipe entries equal to the defaults they override: {redundant}"
    assert {(RECIPES, "FASTSAC_GO1", "v_min"), (RECIPES, "PPO_ALLEGRO_ROTATE_TASK", "reset_press"),
            (RECIPES, "MANIPULATION_RECIPE", "utd")} <= set(needed)


def test_no_launcher_argument_equals_its_default(calls):
    """``default_total_steps=1_000_000``, ``default_num_envs=8192`` ... only where the launcher's default differs."""
    redundant = []
    for script, (launcher, given, _, _) in calls.items():
        fn = inspect.signature(getattr(importlib.import_module(LAUNCHERS[launcher]), launcher))
        for name, value in given.items():
            default = fn.parameters[name].default
            if name not in RECIPE_PARAMS and default is not inspect.Parameter.empty and value == default:
                redundant.append(f"{script} {launcher}({name}={value!r})")
    assert not redundant, f"launcher arguments equal to their defaults: {redundant}"


def test_time_to_target_flags_differ_from_the_scripts_defaults(calls):
    """bench/time_to_target.py's per-configuration flags: none repeats the default the script runs with (its
    launcher's ``default_<flag>``, else the flag's own default)."""
    from absl import flags

    spec = importlib.util.spec_from_file_location("time_to_target", os.path.join(ROOT, "bench", "time_to_target.py"))
    ttt = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ttt)
    redundant, checked = [], 0
    for config_name, config in ttt.CONFIGS.items():
        _, _, arguments, _ = calls[os.path.basename(config["script"])]
        for flag in config.get("flags", []):
            name, value = flag.removeprefix("--").split("=", 1)
            parsed = flags.FLAGS[name].parser.parse(value)
            default = arguments.get(f"default_{name}", flags.FLAGS[name].default)
            checked += 1
            if parsed == default:
                redundant.append(f"{config_name}: {flag}")
    assert checked and not redundant, f"time_to_target flags equal to the scripts' defaults: {redundant}"



def test_every_script_runs_its_recipe_from_unilab_jax_recipes(calls):
    """The scripts hold no recipe of their own: each passes its launcher ``recipes.get(script).kwargs``."""
    from unilab_jax import recipes

    assert set(recipes.names()) == {script[:-3] for script in calls}
    for script, (launcher, given, _, _) in calls.items():
        recipe = recipes.get(script)
        assert recipe.launcher == launcher and dict(recipe.kwargs) == given, script
    go1 = recipes.get("fastsac_go1")
    assert (go1.algo, go1.task, go1.recipe, go1.total_steps) == ("fastsac", "go1_joystick_flat",
                                                                 {"v_min": -0.5, "v_max": 1.5, "utd": 12 / 1024},
                                                                 50_000_000)
    assert recipes.get("sac_cartpole").train_args()["total_steps"] == 1_000_000
    with pytest.raises(ValueError, match="unknown recipe"):
        recipes.get("nope")
