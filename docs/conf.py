"""Sphinx configuration of the anra_torch documentation site (``make docs`` builds it offline, strict).

Sphinx rather than MkDocs: the package's docstrings cross-reference with Sphinx roles (``:func:``,
``:class:``, ``:data:``, ``:mod:``) throughout; Sphinx resolves every one of them and, in nitpicky mode with
warnings as errors, fails the build on a broken one. Pages are Markdown (MyST); the API reference is
generated from the docstrings (autodoc, Google style through napoleon).
"""

from __future__ import annotations

import functools

import anra_torch

project = "anra_torch"
author = "anra_torch developers"
release = version = anra_torch.__version__
copyright = "2026, anra_torch developers"  # noqa: A001 - Sphinx's name

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
myst_enable_extensions = ["colon_fence", "dollarmath"]
myst_heading_anchors = 3
exclude_patterns = ["_build"]
html_theme = "furo"
html_title = "anra_torch"
html_static_path: list[str] = []

autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_typehints_format = "short"
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_ivar = True  # "Attributes:" as fields: autodoc documents the attributes themselves once
napoleon_custom_sections = ["Shape", ("Example", "examples_style")]  # Shape: as written (a tuple of
# letters in parentheses read as a parameter's type broke the literals)

nitpicky = False  # `sphinx-build -n` turns it on: about 110 references to private or unexported names remain
nitpick_ignore_regex = [
    # Types of other libraries: no inventory is fetched (the build is offline).
    (
        r"py:.*",
        r"(torch|numpy|np|nn|scipy|matplotlib|collections|typing|pathlib|argparse|os|dataclasses)\..*",
    ),
    (r"py:.*", r"(Tensor|Path|Any|Callable|Sequence|Iterable|Iterator|Mapping|PathLike|ndarray|Generator)"),
    (r"py:.*", r"(int|float|str|bool|dict|list|tuple|object|None|bytes|type|slice|complex)"),
]


# -- The API reference: one page per subpackage, generated from its face ----------------------------------
# Users import from ``anra_torch`` and from each subpackage's ``__init__``; its ``__all__`` is the public
# surface. Each public object gets one page, at the lowest face (bottom up, as the layers run) that exports
# it; a face that re-exports a name from below links to that page instead of documenting it twice.

import importlib  # noqa: E402
import inspect  # noqa: E402
import types  # noqa: E402
from pathlib import Path  # noqa: E402

SUBPACKAGES = (
    ("checks", "Input checks and result flags"),
    ("layers", "Layers on fixed kernels"),
    ("balance", "The PDE balance"),
    ("video", "Videos, formats and preparation"),
    ("simulation", "Simulation"),
    ("estimation", "Estimation"),
    ("effects", "Effects"),
    ("selection", "Selection"),
    ("forecast", "Forecasts"),
    ("tissue", "Tissue"),
    ("flash", "Flash thermography"),
    ("report", "Reports"),
    ("recording", "Recordings"),
    ("batch", "Batch"),
    ("data", "Data for DataLoaders"),
    ("cli", "Command line"),
)
"""The subpackages, bottom up (``tests/test_architecture.py`` holds the layers)."""

_API = Path(__file__).parent / "api"


def _write_if_changed(path: Path, text: str) -> None:
    if not path.exists() or path.read_text() != text:
        path.write_text(text)


def _home(module: str, obj: object) -> str | None:
    """The module that defines ``obj`` (None for a constant)."""
    if inspect.ismodule(obj):
        return obj.__name__
    if isinstance(obj, types.UnionType | types.GenericAlias):  # a type alias: documented where exported
        return None
    return getattr(obj, "__module__", None) if callable(obj) or inspect.isclass(obj) else None


def _key(obj: object) -> object:
    """What makes two exported names one object: identity, or for a type alias its text (``PathLike`` is
    ``str | os.PathLike[str]`` written twice)."""
    return repr(obj) if isinstance(obj, types.UnionType) else id(obj)


def _directive(obj: object) -> str:
    if inspect.isclass(obj):
        return ".. autoclass::"
    return ".. autofunction::" if callable(obj) else ".. autodata::"


def _api_pages() -> None:
    """Write ``api/<subpackage>.md`` for every face (ignored by git: the faces are the source).

    One page per subpackage (as kornia has one per module): its summary table, then every name it owns.
    A page per name (autosummary's ``:toctree:``) made 340 pages whose navigation furo renders on each:
    over two minutes of the build."""
    documented: dict[object, str] = {}
    for sub, title in SUBPACKAGES:
        face = f"anra_torch.{sub}"
        module = importlib.import_module(face)
        own, elsewhere = [], []
        for name in module.__all__:
            obj = getattr(module, name)
            home = _home(face, obj)
            if _key(obj) in documented or (home is not None and not home.startswith(face)):
                elsewhere.append((name, documented.get(_key(obj)) or f"{home}.{name}"))
                continue
            documented[_key(obj)] = f"{face}.{name}"
            own.append(name)
        lines = [
            f"# `{face}`: {title}",
            "",
            "```{eval-rst}",
            f".. automodule:: {face}",
            "   :no-members:",
            "",
        ]
        if own:
            lines += [".. autosummary::", "   :nosignatures:", ""]
            lines += [f"   {name}" for name in own]  # the current module is the face
            lines.append("")
            lines += [f"{_directive(getattr(module, name))} {face}.{name}" for name in own]
        lines.append("```")
        if elsewhere:
            lines += ["", "Also exported here, documented where they are defined:", "", "```{eval-rst}"]
            lines += [".. autosummary::", "   :nosignatures:", ""]
            lines += [f"   {target.removeprefix(face + '.')}" for _, target in elsewhere]
            lines.append("```")
        _write_if_changed(_API / f"{sub}.md", "\n".join(lines) + "\n")
    top = importlib.import_module("anra_torch")
    lines = [
        "# `anra_torch`: the everyday names",
        "",
        "```{eval-rst}",
        ".. automodule:: anra_torch",
        "   :no-members:",
        "",
        ".. autosummary::",
        "   :nosignatures:",
        "",
    ]
    lines += [
        f"   {documented[_key(getattr(top, name))].removeprefix('anra_torch.')}" for name in top.__all__
    ]
    lines.append("```")
    _write_if_changed(_API / "anra_torch.md", "\n".join(lines) + "\n")


_api_pages()


# -- Cross-references to where a name is documented -------------------------------------------------------
# Docstrings name objects where they are defined (``anra_torch.estimation.estimator.ANRAEstimator``,
# ``:mod:`~anra_torch.simulation.integrator```, ``:func:`integrate``` inside that module); the site documents
# them once, at their face. A reference that does not resolve as written is resolved to that public page:
# a module to its subpackage's face, an object to its page, a member to its class's page. What does not name
# an object of the package at all still fails the build.

import pkgutil  # noqa: E402

from sphinx.pycode import ModuleAnalyzer  # noqa: E402


def _public_names() -> dict[int, str]:
    found: dict[int, str] = {}
    for sub, _ in SUBPACKAGES:
        module = importlib.import_module(f"anra_torch.{sub}")
        for name in module.__all__:
            found.setdefault(id(getattr(module, name)), f"anra_torch.{sub}.{name}")
    return found


_PUBLIC = _public_names()
_ALL_MODULES = [
    info.name
    for info in pkgutil.walk_packages(anra_torch.__path__, "anra_torch.")
    if not info.name.endswith("__main__")
]


def _lookup(dotted: str) -> tuple[object, str] | None:
    """The object ``dotted`` names and the public name it is documented under (a member keeps its tail)."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj: object = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        public = obj.__name__.split(".")[:2]  # a module: its subpackage's face
        tail: list[str] = []
        for i, attr in enumerate(parts[cut:]):
            if not hasattr(obj, attr):
                return None
            obj = getattr(obj, attr)
            if id(obj) in _PUBLIC:
                public, tail = _PUBLIC[id(obj)].split("."), []
            else:
                tail = [*tail, attr] if tail or i else [attr]
        return obj, ".".join(public + tail)
    return None


def _resolve_to_public(app, env, node, contnode):  # noqa: ANN001, ANN202 - Sphinx's event signature
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"]
    context = [node.get("py:module"), node.get("py:class")]
    prefixes = [""]
    if context[0]:
        prefixes += [f"{context[0]}.", *(f"{context[0]}.{context[1]}." for _ in [0] if context[1])]
    for prefix in reversed(prefixes):
        found = _lookup(prefix + target) if (prefix + target).startswith("anra_torch") else None
        if found is None:
            continue
        obj, public = found
        domain = env.get_domain("py")
        kind = "mod" if public.count(".") == 1 and inspect.ismodule(obj) else "obj"
        resolved = domain.resolve_xref(env, node["refdoc"], app.builder, kind, public, node, contnode)
        if resolved is not None:
            return resolved
    return None


@functools.cache
def _attribute_docs() -> dict[str, list[str]]:
    """The ``#:`` or string docstrings of module-level names, by name, over the package's modules."""
    docs: dict[str, list[str]] = {}
    for name in _ALL_MODULES:
        try:
            analyzer = ModuleAnalyzer.for_module(name)
            analyzer.analyze()
        except Exception:  # noqa: BLE001, S112 - a module without source: nothing to read
            continue
        for (scope, attr), lines in analyzer.attr_docs.items():
            if scope == "" and lines:
                docs.setdefault(attr, list(lines))
    return docs


def _constant_docstring(app, what, name, obj, options, lines):  # noqa: ANN001, ANN202 - Sphinx's signature
    """A constant re-exported by a face has no docstring there; take the one beside its definition,
    not its type's (a ``dict``'s docstring is no description of a registry)."""
    if what == "data" and lines and type(obj).__doc__ and lines[0] in type(obj).__doc__:
        lines[:] = _attribute_docs().get(name.rsplit(".", 1)[-1], [])


def setup(app):  # noqa: ANN001, ANN201 - Sphinx's signature
    app.connect("missing-reference", _resolve_to_public)
    app.connect("autodoc-process-docstring", _constant_docstring)


# -- The commands' flags: from the argument parser itself -------------------------------------------------


def _commands_page() -> None:
    """Write ``reference/commands.md``: every command's ``--help``, as ``anra`` prints it (ignored by git)."""
    import argparse
    import os

    from anra_torch.cli import build_parser

    os.environ["COLUMNS"] = "110"  # argparse wraps to the terminal; the page does not depend on it
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]  # noqa: SLF001
    lines = [
        "# Commands and flags",
        "",
        "Generated from the argument parser at every build: each command's `--help`, as `anra` prints it. "
        "What the outputs mean is in the [output reference](outputs.md).",
        "",
        "```text",
        parser.format_help().rstrip(),
        "```",
    ]
    for name, command in sub.choices.items():
        lines += ["", f"## `anra {name}`", "", "```text", command.format_help().rstrip(), "```"]
    (Path(__file__).parent / "reference").mkdir(exist_ok=True)
    _write_if_changed(Path(__file__).parent / "reference" / "commands.md", "\n".join(lines) + "\n")


_commands_page()
