"""The package's layers: every import points down the data path, and no modules import each other in a circle.

Every import counts: at module level, inside functions and under TYPE_CHECKING alike.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]

# A layer may import its own modules and those of lower ranks; equal ranks are independent of each other.
RANKS = {
    "robots": 0,
    "sims": 1,
    "benchmark.common": 2,
    "benchmark.trial": 3,
    "benchmark.llm": 4,
    "benchmark.training": 4,
    "benchmark.plugins": 4,
    "benchmark.experiments": 5,
    "benchmark.checks": 5,
    "benchmark.evaluate": 6,
    "benchmark.cli": 7,
}


def layer_of(module: str) -> str | None:
    best = None
    for name in RANKS:
        if (module == name or module.startswith(name + ".")) and (best is None or len(name) > len(best)):
            best = name
    return best


def modules() -> dict[str, Path]:
    out = {}
    for top in ("benchmark", "sims", "robots"):
        for path in sorted((ROOT / top).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imports_of(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The project modules `name` imports (a `from package import module` names the module)."""
    out = set()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[:len(package.split(".")) - node.level + 1] + ([base] if base else []))
            for alias in node.names:
                out.add(f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base)
    return {m for m in out if m in known and m != name}


def test_the_layer_table_covers_every_module():
    assert [m for m in modules() if layer_of(m) is None and m != "benchmark"] == []


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    known = modules()
    return {name: imports_of(name, path, known) for name, path in known.items()}


def test_no_import_runs_up_a_layer_or_across(graph):
    wrong = []
    for module, targets in graph.items():
        mine = layer_of(module)
        for target in targets:
            theirs = layer_of(target)
            if module == "benchmark" or theirs == mine or theirs is None:
                continue
            if RANKS[theirs] >= RANKS[mine]:
                wrong.append(f"{module} -> {target} ({mine} may not import {theirs})")
    assert wrong == []


def test_no_modules_import_each_other_in_a_circle(graph):
    state: dict[str, int] = {}
    circles = []

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                circles.append(" -> ".join(path[path.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert circles == []


def test_the_checker_sees_an_upward_import_and_a_circle(tmp_path):
    """The checks above can fail: a made-up trial module that imports the CLI is caught, and so is a circle."""
    known = {"benchmark.trial.x": tmp_path / "x.py", "benchmark.trial.y": tmp_path / "y.py",
             "benchmark.cli.main": tmp_path / "main.py"}
    (tmp_path / "x.py").write_text("def f():\n    from benchmark.cli.main import main\n    from benchmark.trial import y\n")
    (tmp_path / "y.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from benchmark.trial.x import f\n")
    assert imports_of("benchmark.trial.x", known["benchmark.trial.x"], known) == {"benchmark.cli.main",
                                                                                  "benchmark.trial.y"}
    assert imports_of("benchmark.trial.y", known["benchmark.trial.y"], known) == {"benchmark.trial.x"}
    assert RANKS[layer_of("benchmark.cli.main")] > RANKS[layer_of("benchmark.trial.x")]
