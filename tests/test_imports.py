"""The package's layering: every module imports, subpackages import only downward (cli -> study ->
experiments -> learn -> scale -> control -> sim -> data, config, errors, files), no chain of imports
inside carl_sumo returns to where it started (imports inside functions and under TYPE_CHECKING count
too), no module is over 500 lines and no function over 80; the old flat module paths still import."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

import carl_sumo

PACKAGE = Path(carl_sumo.__file__).parent


def modules() -> dict[str, Path]:
    """Dotted name -> file of every module of the package."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports anywhere in its source."""
    mods = modules()

    def resolve(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for name, path in mods.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                deps.update(resolve(a.name) for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative import
                    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
                    for _ in range(node.level - 1):
                        package = package.rpartition(".")[0]
                    base = f"{package}.{base}".rstrip(".")
                for alias in node.names:  # `from carl_sumo.experiments import figures` imports a module
                    full = f"{base}.{alias.name}"
                    deps.add(full if full in mods else resolve(base))
        graph[name] = {d for d in deps if d is not None and d.startswith("carl_sumo")} - {name}
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the graph as a list of modules (first = last), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        path.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (found := visit(start)):
            return found
    return None


@pytest.mark.parametrize("name", sorted(modules()))
def test_every_module_imports(name):
    importlib.import_module(name)


def test_the_import_graph_has_no_cycle():
    graph = import_graph()
    assert "carl_sumo.experiments.figures" in graph["carl_sumo.experiments.evaluate"]  # the graph sees lazy imports
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_finder_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


#: the layers from the bottom: a module imports only from its own layer and the ones below
LAYERS = ["", "sim", "control", "scale", "learn", "experiments", "manoeuvres", "study", "cli"]


def layer(module: str) -> int:
    """The rank of a module's layer: 0 for the root modules (config, errors, files) and data."""
    sub = module.split(".")[1] if "." in module else ""
    if sub == "__main__":
        return LAYERS.index("cli")
    return LAYERS.index(sub) if sub in LAYERS else 0


def test_subpackages_import_only_downward():
    upward = sorted(f"{a} -> {b}" for a, deps in import_graph().items() for b in deps
                    if layer(b) > layer(a))
    assert not upward, "imports against the layering: " + "; ".join(upward)


def test_the_layer_check_sees_an_upward_import():
    assert layer("carl_sumo.sim.sumo") < layer("carl_sumo.learn.train") < layer("carl_sumo.cli")
    assert layer("carl_sumo.config") == layer("carl_sumo.data.events") == 0


def test_every_subpackage_is_a_layer():
    subs = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()} - {"data"}
    assert subs == set(LAYERS) - {""}


MAX_FUNCTION_LINES = 80
"""Functions stay readable; modules are as long as their one concept needs (no line cap: code
was once moved between modules only to stay under one)."""


def test_functions_stay_short():
    long = []
    for name, path in modules().items():
        text = path.read_text()
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                size = node.end_lineno - node.lineno + 1
                if size > MAX_FUNCTION_LINES:
                    long.append(f"{name}.{node.name}: {size} lines")
    assert not long, "too long: " + "; ".join(long)


def test_the_public_api_of_the_docs_imports():
    from carl_sumo.learn.agents import Agent, AgentConfig  # noqa: F401
    from carl_sumo.control.cacc import PloegController, ploeg_controller  # noqa: F401
    from carl_sumo.cli import main  # noqa: F401
    from carl_sumo.sim.metrics import aggregate, score_event  # noqa: F401
    from carl_sumo.learn.policy import load_policy, load_torch  # noqa: F401
    from carl_sumo.learn.replay_buffer import ReplayBuffer  # noqa: F401
    from carl_sumo.experiments.simulate import cached_sim, run_event, simulate  # noqa: F401
    from carl_sumo.study import StudyConfig, run_one  # noqa: F401
    from carl_sumo.sim.sumo import DEFAULT_NET, PlatoonSim  # noqa: F401
