"""The package's structure, measured from its source: sizes, layers, import cycles, one home per mechanism.

These are the architecture's promises: a module stays under 450 lines, a function under 60 and a public
function takes at most 10 parameters, with no exception; the top level
holds only ``__init__``, ``__main__`` and subpackages, each with a face (``__init__``) that the others import
from; the subpackages form layers and every import runs down them; no two modules import each other,
directly or around a circle (the experiments' scripts included); no module hides an import of the package
inside a function; the ODE solver is called in one place; an effect lives in its own module and nothing
else branches on its name or keeps a table of names; the top-level surface stays small; the tests mirror
the package, every module with its test file; the package's tests import neither the experiments nor the
benchmarks.
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
EXPERIMENTS = PACKAGE.parent / "experiments"
BENCHMARKS = PACKAGE.parent / "benchmarks"
SCRIPT_FOLDERS = ("experiments", "benchmarks")
SCRIPTS = sorted([*EXPERIMENTS.glob("*.py"), *BENCHMARKS.glob("*.py")])
TESTS = Path(__file__).resolve().parent

LAYERS: tuple[tuple[str, ...], ...] = (
    ("checks",),
    ("layers",),
    ("balance",),
    ("video",),
    ("simulation",),
    ("estimation", "effects"),
    ("selection",),
    ("forecast", "tissue", "flash"),
    ("report", "recording"),
    ("batch", "data"),
    ("cli",),
)
"""The subpackages from the bottom up: a subpackage imports only from the layers below its own."""

LAZY_IMPORTS = {
    "distributed": "the dask extra",
    "pyarrow": "the parquet extra",
    "matplotlib": "the plot extra",
    "flyr": "the formats extra",
    "h5py": "the formats extra",
    "tifffile": "the formats extra",
    "imagecodecs": "the formats extra",
    "scipy": "the test extra (the independent 3-D bioheat simulator, a reference for tests and experiments)",
    "torchdiffeq": "loads scipy.integrate (0.4 s at every start of commands that integrate nothing)",
    "kornia": "the paper's naive baselines only (0.2 s at every start of every command)",
}
"""Third-party modules a function may import (optional extras; the one measured start-up cost)."""


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MAX_MODULE_LINES = 450
MAX_FUNCTION_LINES = 60
MAX_PUBLIC_PARAMETERS = 10
"""The caps: lines per module, lines per function (``end_lineno - lineno + 1``, decorators excluded, the
docstring included), parameters of a public function (``self`` and keyword-only ones counted, ``*args``
and ``**kwargs`` not): settings that travel together are a named dataclass."""


def _functions(path: Path) -> list[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef]]:
    """Every function of a module with its qualified name (``module.Class.method``, ``module.f.inner``)."""
    found = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                name = f"{prefix}.{child.name}"
                if not isinstance(child, ast.ClassDef):
                    found.append((name, child))
                visit(child, name)
            else:
                visit(child, prefix)

    visit(ast.parse(path.read_text()), module_name(path))
    return found


def _largest(pairs: list[tuple[str, int]]) -> dict[str, int]:
    """The largest value of each name (a property's getter and setter share theirs)."""
    out: dict[str, int] = {}
    for name, value in pairs:
        out[name] = max(value, out.get(name, value))
    return out


def _over(measured: dict[str, int], cap: int) -> list[str]:
    """What is over ``cap``, with its size (no exceptions: the last ones were brought under the caps)."""
    return sorted(f"{name}: {size} (cap {cap})" for name, size in measured.items() if size > cap)


def test_no_module_over_the_line_cap() -> None:
    sizes = {module_name(p): p.read_text().count("\n") for p in MODULES}
    assert _over(sizes, MAX_MODULE_LINES) == []


def test_no_function_over_the_line_cap() -> None:
    lengths = _largest(
        [(name, node.end_lineno - node.lineno + 1) for path in MODULES for name, node in _functions(path)]  # type: ignore[operator]
    )
    assert _over(lengths, MAX_FUNCTION_LINES) == []


def test_no_public_function_over_the_parameter_cap() -> None:
    counts = _largest(
        [
            (name, len(node.args.posonlyargs) + len(node.args.args) + len(node.args.kwonlyargs))
            for path in MODULES
            for name, node in _functions(path)
            if not node.name.startswith("_")
        ]
    )
    assert _over(counts, MAX_PUBLIC_PARAMETERS) == []


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


def _layer(package: str) -> int:
    return next(i for i, names in enumerate(LAYERS) if package in names)


def _imports(path: Path) -> list[ast.ImportFrom | ast.Import]:
    return [n for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.ImportFrom | ast.Import)]


def test_the_top_level_holds_only_the_face_and_subpackages() -> None:
    loose = sorted(p.name for p in PACKAGE.glob("*.py") if p.name not in ("__init__.py", "__main__.py"))
    assert not loose
    packages = sorted(p.name for p in PACKAGE.iterdir() if p.is_dir() and p.name != "__pycache__")
    assert all((PACKAGE / name / "__init__.py").exists() for name in packages)
    assert sorted(packages) == sorted(name for names in LAYERS for name in names if (PACKAGE / name).exists())


def test_every_import_runs_down_the_layers_through_a_face() -> None:
    upward, past_face = [], []
    for path in MODULES:
        parts = path.relative_to(PACKAGE).parts
        if len(parts) < 2:
            continue
        own = parts[0]
        for node in _imports(path):
            if not isinstance(node, ast.ImportFrom) or not (node.module or "").startswith("anra_torch."):
                continue
            target = node.module.split(".")
            if target[1] == own:
                continue
            if _layer(target[1]) >= _layer(own):
                upward.append(f"{module_name(path)} -> {node.module}")
            if len(target) > 2:
                past_face.append(f"{module_name(path)} -> {node.module}")
    assert not upward
    assert not past_face


def test_no_import_hides_in_a_function() -> None:
    hidden = []
    for path in MODULES:
        tree = ast.parse(path.read_text())
        top = {id(n) for node in tree.body for n in ast.walk(node) if isinstance(node, ast.If)}
        top |= {id(node) for node in tree.body}
        top |= {id(n) for node in tree.body if isinstance(node, ast.Try) for n in node.body}  # module level
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom) and id(node) not in top:
                names = [node.module] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
                hidden += [
                    f"{module_name(path)}: {name}" for name in names if name.split(".")[0] not in LAZY_IMPORTS
                ]
    assert not hidden


def test_no_table_of_effect_names_outside_effects() -> None:
    """A tuple, list, set or dict naming two or more effects (or an ``in`` test against one) outside
    ``effects/`` is a registry keyed by name: such a fact belongs to each effect's spec."""
    names = set(EFFECTS)
    tables = []
    for path in MODULES:
        if path.parent.name == "effects":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            items = []
            if isinstance(node, ast.Tuple | ast.List | ast.Set):
                items = node.elts
            elif isinstance(node, ast.Dict):
                items = [k for k in node.keys if k is not None]
            named = [i.value for i in items if isinstance(i, ast.Constant) and i.value in names]
            if len(named) >= 2:
                tables.append(f"{module_name(path)}:{node.lineno}: {named}")
    assert not tables


def _experiment_imports(path: Path) -> set[str]:
    """The scripts of ``experiments/`` and ``benchmarks/`` that a file imports, as ``folder.NAME``."""
    found = set()
    for node in _imports(path):
        names = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
        found |= {".".join(n.split(".")[:2]) for n in names if n.split(".")[0] in SCRIPT_FOLDERS and "." in n}
    return found


def test_the_experiments_import_each_other_without_a_circle_or_a_path_edit() -> None:
    scripts = {f"{p.parent.name}.{p.stem}": p for p in SCRIPTS if p.stem != "__init__"}
    graph = {name: _experiment_imports(path) & set(scripts) for name, path in scripts.items()}
    assert not [name for name, path in scripts.items() if "sys.path" in path.read_text()]
    state: dict[str, int] = {}
    cycles = []

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append([*path[path.index(nxt) :], nxt])
            elif nxt not in state:
                visit(nxt, [*path, nxt])
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    assert not cycles


def test_the_package_never_imports_the_experiments_or_benchmarks() -> None:
    importing = [module_name(p) for p in MODULES if _experiment_imports(p)]
    assert not importing


def test_the_package_tests_never_import_the_experiments_or_benchmarks() -> None:
    """Only the experiments' own tests (``tests/experiments/``) import them: a helper that a test and a script
    both need lives under ``tests/`` (the scripts import it as ``tests.NAME``)."""
    importing = []
    for path in sorted(TESTS.rglob("*.py")):
        if path.relative_to(TESTS).parts[0] in SCRIPT_FOLDERS:
            continue
        for node in _imports(path):
            names = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
            if any(name.split(".")[0] in ("experiments", "benchmarks") for name in names):
                importing.append(f"{path.relative_to(TESTS)}:{node.lineno}")
    assert not importing


def mirrored_test(path: Path) -> Path | None:
    """Where a module's tests live: ``tests/<subpackage>/test_<module>.py`` (``__main__``: ``test_main.py``).

    A package's ``__init__`` that defines functions or classes (more than a face) keeps its tests in
    ``test_<package>.py`` beside its modules'; a face that only re-exports needs none.
    """
    relative = path.relative_to(PACKAGE)
    if path.name != "__init__.py":
        return TESTS / relative.parent / f"test_{path.stem.strip('_')}.py"
    body = ast.parse(path.read_text()).body
    if relative.parent == Path(".") or not any(isinstance(n, ast.FunctionDef | ast.ClassDef) for n in body):
        return None
    return TESTS / relative.parent / f"test_{relative.parent.name}.py"


def test_every_module_has_its_test_file_at_the_mirrored_path() -> None:
    expected = {module_name(p): mirrored_test(p) for p in MODULES}
    missing = sorted(f"{name}: {test.relative_to(TESTS.parent)}" for name, test in expected.items()
                     if test is not None and not test.is_file())  # fmt: skip
    assert not missing


def test_every_test_file_in_a_folder_mirrors_a_module() -> None:
    """``tests/<path>/test_<name>.py`` tests ``anra_torch/<path>/<name>.py`` (or the package ``<path>``
    itself), ``tests/experiments/test_<name>.py`` the script ``experiments/<name>.py``; package-wide
    tests stay at the top of ``tests/``."""
    mirrored = {test for p in MODULES if (test := mirrored_test(p)) is not None}
    scripts = {TESTS / p.parent.name / f"test_{p.stem}.py" for p in SCRIPTS}
    stray = sorted(
        str(p.relative_to(TESTS.parent))
        for p in TESTS.rglob("test_*.py")
        if p.parent != TESTS and p not in mirrored | scripts
    )
    assert not stray
