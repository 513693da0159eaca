"""How dense the package's docstrings are: parentheses per 100 words, against peer libraries.

Reads every module, class and function docstring (``ast.get_docstring``) of a package's source without
importing it, and counts opening parentheses ``(`` and words (runs of letters, digits and ``_``). A
docstring that keeps to the contract (what, units, shapes, raises) has few asides; essays, derivations and
measurement notes in parentheses raise the density. Prints one line per package: docstrings, words,
parentheses, parentheses per 100 words, and the same in the prose alone (``prose``: without code in
backticks and example lines, where shapes and formulas keep their parentheses). With ``--worst N``, the N
modules of the first package with the most prose parentheses, the first to move to the docs pages; with
``--subpackages``, the same line for each subpackage of the first package (its top-level modules as ``.``).

Usage::

    python -m benchmarks.docstring_density                       # anra_torch and the peers installed
    python -m benchmarks.docstring_density anra_torch --worst 15
    python -m benchmarks.docstring_density anra_torch --subpackages
    python -m benchmarks.docstring_density anra_torch kornia pde pysindy

A package is found by import name (its folder from ``importlib.util.find_spec``, nothing is imported);
peers that are not installed are skipped with a note.
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import re
import sys
from dataclasses import dataclass
from pathlib import Path

PEERS = ("kornia", "pde", "pysindy")
"""kornia, py-pde and pysindy: the peers the issue measured against."""

WORD = re.compile(r"\w+")
CODE = re.compile(r"``.*?``|`[^`\n]*`|^\s*(>>>|\.\.\.).*$", re.M | re.S)
"""Inline code (double or single backticks) and doctest lines: what the prose count leaves out."""


@dataclass
class Density:
    """Counts over the docstrings of one package or module."""

    docstrings: int = 0
    words: int = 0
    parentheses: int = 0
    prose_words: int = 0
    prose_parentheses: int = 0

    @property
    def per_100_words(self) -> float:
        return 100.0 * self.parentheses / self.words if self.words else float("nan")

    @property
    def prose_per_100_words(self) -> float:
        return 100.0 * self.prose_parentheses / self.prose_words if self.prose_words else float("nan")

    def add(self, text: str) -> None:
        self.docstrings += 1
        self.words += len(WORD.findall(text))
        self.parentheses += text.count("(")
        prose = CODE.sub(" ", text)
        self.prose_words += len(WORD.findall(prose))
        self.prose_parentheses += prose.count("(")


def docstrings(path: Path) -> list[str]:
    """Every module, class and function docstring of one source file."""
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"))
    except (SyntaxError, UnicodeDecodeError):
        return []
    nodes = [
        tree,
        *(n for n in ast.walk(tree) if isinstance(n, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)),
    ]
    return [text for node in nodes if (text := ast.get_docstring(node, clean=True))]


def package_folder(name: str) -> Path | None:
    """The source folder of an installed (or local) package, without importing it."""
    local = Path(name)
    if (local / "__init__.py").is_file():
        return local
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


def measure(folder: Path) -> tuple[Density, dict[str, Density]]:
    """The density of the whole package and of each module (by path relative to the package's parent)."""
    total, modules = Density(), {}
    for path in sorted(folder.rglob("*.py")):
        module = Density()
        for text in docstrings(path):
            total.add(text)
            module.add(text)
        modules[str(path.relative_to(folder.parent))] = module
    return total, modules


def by_subpackage(modules: dict[str, Density]) -> dict[str, Density]:
    """The modules' counts summed per subpackage (``package/sub/...``); top-level modules count as ``.``."""
    groups: dict[str, Density] = {}
    for path, d in modules.items():
        parts = Path(path).parts
        group = groups.setdefault(parts[1] if len(parts) > 2 else ".", Density())
        group.docstrings += d.docstrings
        group.words += d.words
        group.parentheses += d.parentheses
        group.prose_words += d.prose_words
        group.prose_parentheses += d.prose_parentheses
    return groups


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("packages", nargs="*", default=["anra_torch", *PEERS], help="import names")
    parser.add_argument(
        "--worst", type=int, default=0, help="list the N modules of the first package with most"
    )
    parser.add_argument(
        "--subpackages", action="store_true", help="one line per subpackage of the first package"
    )
    args = parser.parse_args(argv)
    print(f"{'package':<12} {'docstrings':>10} {'words':>8} {'parens':>7} {'per 100 words':>14} {'prose':>7}")
    first: dict[str, Density] = {}
    for index, name in enumerate(args.packages):
        folder = package_folder(name)
        if folder is None:
            print(f"{name:<12} not installed, skipped", file=sys.stderr)
            continue
        total, modules = measure(folder)
        first = modules if index == 0 else first
        counts = f"{total.docstrings:>10} {total.words:>8} {total.parentheses:>7}"
        print(f"{name:<12} {counts} {total.per_100_words:>14.2f} {total.prose_per_100_words:>7.2f}")
    if args.subpackages:
        print(f"\nsubpackages of {args.packages[0]}:")
        for name, d in sorted(by_subpackage(first).items()):
            counts = f"{d.docstrings:>10} {d.words:>8} {d.parentheses:>7}"
            print(f"  {name:<10} {counts} {d.per_100_words:>14.2f} {d.prose_per_100_words:>7.2f}")
    if args.worst:
        print(f"\nmodules with the most prose parentheses in {args.packages[0]}:")
        ranked = sorted(first.items(), key=lambda item: -item[1].prose_parentheses)[: args.worst]
        for path, d in ranked:
            print(
                f"  {path:<48} {d.prose_parentheses:>4} in prose ({d.prose_per_100_words:5.2f} per 100 words)"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
