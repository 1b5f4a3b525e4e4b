"""Imports run one way: no module imports a module of a higher layer, and the import graph has no circles.

The layers are docs/ARCHITECTURE.md's ("Layers"); ``LAYERS`` below mirrors that picture. Every import
statement counts, module-level or inside a function, absolute or relative; a module name reached only
through ``importlib.import_module`` of a string in a registry table (algorithms, learners, tasks, shim
backends) is not an import statement and is how a lower layer may name a higher one.
"""

from __future__ import annotations

import ast
import fnmatch
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGES = ("unilab_jax", "unilab_mlx", "tasks", "experiments")

# (module-name pattern, layer), first match wins; a module no pattern matches fails the test. A layer group's
# sub-layers (2.0 robots < 2.1 tasks < 2.2 runtime < 2.3 checkpoints, ...) order the modules inside the group,
# so an import that runs back up inside a group (a robot module importing the runtime) fails like any other.
LAYERS = [
    # L0: the array-API shim and its MLX backend
    ("unilab_jax.xp", 0), ("unilab_jax.mixed_precision", 0), ("unilab_jax.pallas_kernels", 0),
    ("unilab_mlx.backend", 0),
    # L1: kernels and utilities (no tasks, no runtime, no algorithm)
    ("unilab_jax", 1), ("unilab_jax.core", 1), ("unilab_jax.core.*", 1), ("unilab_jax.nets", 1),
    ("unilab_jax.nets_temporal", 1), ("unilab_jax.config", 1), ("unilab_jax.metrics", 1),
    ("unilab_jax.fields", 1), ("unilab_jax.lazy", 1), ("unilab_jax.sizing", 1), ("unilab_mlx", 1), ("unilab_mlx.*", 1),
    ("unilab_jax.recipes", 1),  # the experiments' recipes as data (names of algorithms and tasks, no imports)
    # the algorithm contract (pure standard library): the runtime reads a declaration's hooks through it
    ("unilab_jax.algos.contract", 1),
    # The command entry points kept at their documented names (python -m unilab_jax.play / .export /
    # .robots.record): one-line forwarders to the applications wing, above everything they forward to.
    ("unilab_jax.play", 7.4), ("unilab_jax.export", 7.4), ("unilab_jax.web", 7.4), ("unilab_jax.robots.record", 7.4),
    # L2: resources: robots (the robot interface, sim robots, servers) < tasks (robot tasks use robot clients)
    # < the runtime (workers build tasks) < checkpoints (which read the runtime's process checks)
    ("unilab_jax.robots", 2.0), ("unilab_jax.robots.*", 2.0),
    ("tasks", 2.1), ("tasks.*", 2.1),
    ("unilab_jax.runtime", 2.2), ("unilab_jax.runtime.*", 2.2),
    ("unilab_jax.checkpoint", 2.3),
    # L4: learners (above the declarations they import)
    ("unilab_jax.algos.*.learner_*", 4), ("unilab_jax.algos.ppo.him_ppo_jax", 4),
    # L3: algorithm declarations (config, act, losses), one folder per family
    ("unilab_jax.algos.*", 3),
    # L5: the registry: (algorithm, platform) -> learner factory, by module path
    ("unilab_jax.algos", 5),
    # L6: the training wing: its parts (threads, batch sources, evaluation, replay mirror and snapshot ...) < the loops
    ("unilab_jax.training", 6.0), ("unilab_jax.training.threads", 6.0), ("unilab_jax.training.sources", 6.0),
    ("unilab_jax.training.evaluation", 6.0), ("unilab_jax.training.device_replay", 6.0),
    ("unilab_jax.training.sharding", 6.0), ("unilab_jax.training.profiling", 6.0),
    ("unilab_jax.training.ring_snapshot", 6.0), ("unilab_jax.training.run_config", 6.0),
    ("unilab_jax.training.compile_cache", 6.0),
    ("unilab_jax.training.trainer", 6.1), ("unilab_jax.training.mjx", 6.1), ("unilab_jax.training.hgdagger", 6.1),
    # L7: the applications wing: saved runs < play, export, record < the experiments' flags < the family CLIs
    ("unilab_jax.apps", 7.0), ("unilab_jax.apps.saved_run", 7.0),
    ("unilab_jax.apps.play", 7.1), ("unilab_jax.apps.export", 7.1), ("unilab_jax.apps.record", 7.1),
    ("unilab_jax.apps.web", 7.1),
    ("unilab_jax.apps.cli_help", 7.1),
    ("unilab_jax.apps.cli", 7.2),
    ("unilab_jax.apps.hora_cli", 7.3), ("unilab_jax.apps.mjx_cli", 7.3), ("unilab_jax.apps.robot_cli", 7.3),
    ("unilab_jax.apps.api", 7.3),  # unilab_jax.train: the experiments' checks (cli.build_run), then the trainer
    # L8: experiment scripts
    ("experiments.*", 8),
]


def layer_of(module: str) -> float:
    for pattern, layer in LAYERS:
        if fnmatch.fnmatchcase(module, pattern):
            return layer
    raise AssertionError(f"{module} is in no layer of tests/test_layers.py (docs/ARCHITECTURE.md, 'Layers')")


def project_modules(root: pathlib.Path = ROOT) -> dict[str, pathlib.Path]:
    modules = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


def _owner(name: str, modules: dict[str, pathlib.Path]) -> str | None:
    """The project module ``name`` is, or (for ``a.b.attr``) lies in; None outside the project."""
    while name:
        if name in modules:
            return name
        name = name.rpartition(".")[0]
    return None


def imports_of(module: str, path: pathlib.Path, modules: dict[str, pathlib.Path]) -> list[tuple[str, int]]:
    """(imported project module, line) for every import statement in ``path``."""
    is_package = path.name == "__init__.py"
    package = module if is_package else module.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(base + ([node.module] if node.module else []))
            else:
                base = node.module
            if module.startswith("experiments.") and base and f"experiments.{base}" in modules:
                base = f"experiments.{base}"  # scripts import their siblings (the script folder is on sys.path)
            names = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names]
        else:
            continue
        for name in names:
            if module.startswith("experiments.") and f"experiments.{name}" in modules:
                name = f"experiments.{name}"
            target = _owner(name, modules)
            if target is not None and target != module:
                found.append((target, node.lineno))
    return found


def import_graph(root: pathlib.Path = ROOT) -> dict[str, list[tuple[str, int]]]:
    modules = project_modules(root)
    return {m: imports_of(m, p, modules) for m, p in modules.items()}


def upward_imports(graph: dict[str, list[tuple[str, int]]]) -> list[str]:
    return [f"{m} (L{layer_of(m)}) imports {t} (L{layer_of(t)}) at line {line}"
            for m, edges in graph.items() for t, line in edges if layer_of(t) > layer_of(m)]


def find_cycle(graph: dict[str, list[tuple[str, int]]]) -> list[str] | None:
    """One circle of imports as [a, b, ..., a], or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for t, _ in graph.get(m, []):
            if state.get(t) == 1:
                return stack[stack.index(t):] + [t]
            if t not in state:
                cycle = visit(t)
                if cycle:
                    return cycle
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            cycle = visit(m)
            if cycle:
                return cycle
    return None


def test_every_module_has_a_layer():
    for module in project_modules():
        layer_of(module)


def test_no_upward_imports():
    bad = upward_imports(import_graph())
    assert not bad, "imports into a higher layer:\n" + "\n".join(bad)


def test_no_import_cycles():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import circle: " + " -> ".join(cycle)


@pytest.mark.parametrize("victim,bad_import,check", [
    ("unilab_jax/algos/offpolicy/sac.py", "from unilab_jax.algos.offpolicy import learner_jax", upward_imports),
    ("unilab_jax/core/gae.py", "from unilab_jax.training import trainer", upward_imports),
    ("tasks/base.py", "import tasks.cartpole", find_cycle),
    ("unilab_jax/algos/offpolicy/sac.py", "from . import fastsac", find_cycle),
    # back up inside a layer group: a robot module reaching the runtime, a training part reaching its loop
    ("unilab_jax/robots/sim.py", "from unilab_jax.runtime import buffers", upward_imports),
    ("unilab_jax/training/threads.py", "from unilab_jax.training import trainer", upward_imports),
    ("unilab_jax/apps/saved_run.py", "from unilab_jax.apps import play", upward_imports),
])
def test_the_checks_catch_a_bad_import(tmp_path, victim, bad_import, check):
    """A copy of the packages with one bad import added inside a function fails the check."""
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            dest = tmp_path / path.relative_to(ROOT)
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_text(path.read_text())
    assert not check(import_graph(tmp_path))
    target = tmp_path / victim
    target.write_text(target.read_text() + f"\n\ndef _bad():\n    {bad_import}\n")
    assert check(import_graph(tmp_path))


SOURCE_PACKAGES = ("unilab_jax", "unilab_mlx", "tasks")
MAX_LINES = 600  # no source file longer than this in unilab_jax/ or tasks/: split it by what its parts do
# A family's JAX and MLX learners share their class and module names on purpose (same interface, one per
# platform, side by side in the family's folder); every other name is defined once.
PLATFORM_TWINS = {"learner_jax", "learner_mlx"}
# Commands kept at their documented names (``python -m unilab_jax.play`` ...): forwarders to the application of
# the same name, and nothing else (checked below).
COMMAND_FORWARDERS = {"unilab_jax/play.py": "unilab_jax.apps.play", "unilab_jax/export.py": "unilab_jax.apps.export",
                      "unilab_jax/web.py": "unilab_jax.apps.web",
                      "unilab_jax/robots/record.py": "unilab_jax.apps.record"}


def _sources(root: pathlib.Path = ROOT) -> list[pathlib.Path]:
    return [p for package in SOURCE_PACKAGES for p in sorted((root / package).rglob("*.py"))]


def test_no_source_file_over_the_limit():
    lengths = {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in _sources()}
    long = [f"{path}: {n} lines" for path, n in lengths.items() if n > MAX_LINES]
    assert not long, f"files over {MAX_LINES} lines:\n" + "\n".join(long)


def test_module_names_do_not_collide():
    seen: dict[str, list[str]] = {}
    for p in _sources():
        if p.stem != "__init__" and str(p.relative_to(ROOT)) not in COMMAND_FORWARDERS:
            seen.setdefault(p.stem, []).append(str(p.relative_to(ROOT)))
    twice = {name: paths for name, paths in seen.items() if len(paths) > 1 and name not in PLATFORM_TWINS}
    assert not twice, f"module names defined more than once: {twice}"


def test_class_names_do_not_collide():
    seen: dict[str, list[pathlib.Path]] = {}
    for p in _sources():
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ClassDef):
                seen.setdefault(node.name, []).append(p)
    twice = {name: [str(p.relative_to(ROOT)) for p in paths] for name, paths in seen.items() if len(paths) > 1
             and not (len({p.parent for p in paths}) == 1 and {p.stem for p in paths} <= PLATFORM_TWINS)}
    assert not twice, f"class names defined more than once: {twice}"


def test_command_forwarders_only_forward():
    for path, target in COMMAND_FORWARDERS.items():
        tree = ast.parse((ROOT / path).read_text())
        imported = [(n.module, [a.name for a in n.names]) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
        assert imported == [(target, ["main"])], f"{path} should only import main from {target}: {imported}"
        assert not [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.ClassDef))], path
