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

# (module-name pattern, layer), first match wins; a module no pattern matches fails the test.
LAYERS = [
    # L0: the array-API shim and its MLX backend
    ("unilab_jax.xp", 0), ("unilab_mlx.backend", 0),
    # L1: kernels and utilities (no tasks, no runtime, no algorithm)
    ("unilab_jax", 1), ("unilab_jax.core", 1), ("unilab_jax.core.*", 1), ("unilab_jax.nets", 1),
    ("unilab_jax.nets_temporal", 1), ("unilab_jax.config", 1), ("unilab_jax.metrics", 1),
    ("unilab_jax.fields", 1), ("unilab_jax.lazy", 1), ("unilab_jax.sizing", 1), ("unilab_mlx", 1), ("unilab_mlx.*", 1),
    # L2: tasks, the runtime (workers load the algorithm declaration by module path) and checkpoints
    # (runtime.ray_pool / runtime.host_rollouts: one host's pool behind pulls, and the learner's pool over Ray nodes)
    ("tasks", 2), ("tasks.*", 2), ("unilab_jax.runtime", 2), ("unilab_jax.runtime.ray_pool", 2),
    ("unilab_jax.runtime.host_rollouts", 2), ("unilab_jax.runtime.*", 2),
    ("unilab_jax.checkpoint", 2), ("unilab_jax.robots", 2), ("unilab_jax.robots.*", 2),
    # L4: learners (above the declarations they import)
    ("unilab_jax.algos.*.learner_*", 4), ("unilab_jax.algos.ppo.him_ppo_jax", 4),
    # L3: algorithm declarations (config, act, losses), one folder per family
    ("unilab_jax.algos.*", 3),
    # L5: the registry: (algorithm, platform) -> learner factory, by module path
    ("unilab_jax.algos", 5),
    # L6: trainer, command lines, MJX baseline, experiment scripts
    ("unilab_jax.trainer", 6), ("unilab_jax.cli", 6), ("unilab_jax.hora_cli", 6), ("unilab_jax.mjx_train", 6),
    ("unilab_jax.mjx_cli", 6), ("unilab_jax.device_replay", 6), ("unilab_jax.sharding", 6), ("experiments.*", 6),
    ("unilab_jax.saved_run", 6), ("unilab_jax.play", 6), ("unilab_jax.export", 6),
    ("unilab_jax.robot_cli", 6), ("unilab_jax.hgdagger", 6),
]


def layer_of(module: str) -> int:
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
    ("unilab_jax/core/gae.py", "from unilab_jax import trainer", upward_imports),
    ("tasks/base.py", "import tasks.cartpole", find_cycle),
    ("unilab_jax/algos/offpolicy/sac.py", "from . import fastsac", find_cycle),
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
