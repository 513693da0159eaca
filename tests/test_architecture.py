"""The package's structure, measured from its source: sizes, import cycles, one home per mechanism.

These are the architecture's promises (README, "Architecture"): a module stays under 600 lines and a
function under 80; no two modules import each other, directly or around a circle; the ODE solver is
called in one place; an effect lives in its own module and nothing else branches on its name; the
top-level surface stays small.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

import anra_torch
from anra_torch.effects import EFFECTS

PACKAGE = Path(anra_torch.__file__).parent
MODULES = sorted(PACKAGE.rglob("*.py"))


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_no_module_over_600_lines() -> None:
    long = {module_name(p): n for p in MODULES if (n := p.read_text().count("\n")) > 600}
    assert not long


def test_no_function_over_80_lines() -> None:
    long = []
    for path in MODULES:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                length = node.end_lineno - node.lineno + 1  # type: ignore[operator]
                if length > 80:
                    long.append(f"{module_name(path)}.{node.name}: {length}")
    assert not long


def module_imports(path: Path) -> set[str]:
    """The package modules a module imports at its top level (imports inside functions are lazy)."""
    names = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("anra_torch"):
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names if a.name.startswith("anra_torch"))
    return names


def test_no_import_cycle() -> None:
    known = {module_name(p): p for p in MODULES}
    graph = {
        name: {m for m in module_imports(path) if m in known and m != name} for name, path in known.items()
    }
    # A package's __init__ re-exports its modules: an edge from a module to its own package is a
    # dependency on its siblings, not on itself. Follow only module -> module edges.
    graph = {name: {m for m in deps if not name.startswith(m + ".")} for name, deps in graph.items()}
    state: dict[str, int] = {}
    cycles = []

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(path[path.index(nxt) :] + [nxt])
            elif nxt not in state:
                visit(nxt, [*path, nxt])
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    assert not cycles


def test_one_integrator() -> None:
    calls = [module_name(p) for p in MODULES if re.search(r"\bodeint\b", p.read_text())]
    assert calls == ["anra_torch.simulation.integrator"]


def test_one_home_for_the_normal_equations() -> None:
    # Products of terms summed over points, minus their noise parts, are assembled by balance.moments only.
    assembling = [
        module_name(p)
        for p in MODULES
        if re.search(r"def (accumulate|extend)\(", p.read_text()) or "flat.T @ flat" in p.read_text()
    ]
    assert assembling == ["anra_torch.balance.moments"]


@pytest.mark.parametrize("name", list(EFFECTS))
def test_an_effect_is_one_module(name: str) -> None:
    module = PACKAGE / "effects" / f"{name}.py"
    assert module.exists() and "SPEC = EffectSpec(" in module.read_text()
    assert EFFECTS[name].name == name


def test_no_branch_on_an_effect_name_outside_its_module() -> None:
    pattern = re.compile(r"==\s*\"(" + "|".join(EFFECTS) + r")\"|\"(" + "|".join(EFFECTS) + r")\"\s*==")
    branching = [
        module_name(p) for p in MODULES if pattern.search(p.read_text()) and p.parent.name != "effects"
    ]
    assert not branching


def test_small_public_surface() -> None:
    assert len(anra_torch.__all__) <= 20
    assert all(hasattr(anra_torch, name) for name in anra_torch.__all__)
