"""The documentation's pages name commands, not commits, and the tests they name exist.

Every number on a results page names the command that reproduces it; none names a commit (issue 38's
acceptance). A commit is recognised as git abbreviates one: 7 to 40 hexadecimal digits standing alone, with at
least one digit (a word such as "defaced" is hexadecimal too) and not part of a decimal number (the digits
after the point of ``8.314462618`` are not a commit). A whole number of 7 digits or more is written with
separators (``4,194,304``) or as a power (``2^22``).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
# docs/conf.py writes these at every build from the docstrings and the parser (git ignores them): what they
# show is the code's, e.g. a default of 16777216 pixel values, not a page's claim.
GENERATED = {DOCS / "reference" / "commands.md"}
GENERATED |= {p for p in (DOCS / "api").glob("*.md") if p.name != "index.md"}
PAGES = sorted(p for p in DOCS.rglob("*.md") if "_build" not in p.parts and p not in GENERATED)
PAGES.append(ROOT / "README.md")
RESULTS = sorted((DOCS / "results").glob("*.md"))
COMMIT = re.compile(r"(?<![\w.,])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}(?![\w]|\.\d)")
COMMAND = re.compile(r"python -m (?:experiments|benchmarks)\.\w+|`anra \w+")
SCRIPT = re.compile(r"python -m ((?:experiments|benchmarks)\.\w+)")
# a test file a page names, ``tests/video/test_resample.py``, and the ``-k WORD`` that may follow it (a
# command may wrap onto the next line)
TEST_PATH = re.compile(r"(?<![\w/.])tests/[\w/]+\.py")
SELECTION = re.compile(r"(?<![\w/.])(tests/[\w/]+\.py)\s+-k\s+(\w+)")


def commits(text: str) -> list[str]:
    """The tokens of ``text`` that look like abbreviated or full commit hashes."""
    return COMMIT.findall(text)


def test_the_commit_pattern() -> None:
    assert commits("at 7701573 (10 seeds), since 5d9783a, before 8ca9d02f and after HEAD") == [
        "7701573",
        "5d9783a",
        "8ca9d02f",
    ]
    full = "e2278f4c0ffee5d9783a0123456789abcdef0123"
    assert commits(f"({full}).") == [full]
    not_commits = "8.314462618 J, 1234567.5 s, 2^22 = 4,194,304, defaced, 123456, 0x7fffffffff, a1b2c3"
    assert commits(not_commits) == []


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_page_names_a_commit(page: Path) -> None:
    found = commits(page.read_text())
    assert found == [], f"{page.relative_to(ROOT)} names commits {found}: say what changed, not where"


def test_the_pages_are_found() -> None:
    assert len(RESULTS) >= 8 and ROOT / "README.md" in PAGES and DOCS / "limits.md" in PAGES


@pytest.mark.parametrize("page", [p for p in RESULTS if p.name != "index.md"], ids=lambda p: p.name)
def test_every_results_page_names_a_command(page: Path) -> None:
    message = f"{page.name} names no `python -m experiments.`, `python -m benchmarks.` nor `anra` command"
    assert COMMAND.search(page.read_text()), message


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_script_a_page_names_exists(page: Path) -> None:
    """``python -m experiments.X`` and ``python -m benchmarks.X`` name a script of that folder (``NAME``
    is the placeholder)."""
    named = set(SCRIPT.findall(page.read_text()))
    missing = sorted(
        name
        for name in named - {"experiments.NAME", "benchmarks.NAME"}
        if not (ROOT / (name.replace(".", "/") + ".py")).is_file()
    )
    assert missing == [], f"{page.relative_to(ROOT)} names scripts that do not exist: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_test_file_a_page_names_exists(page: Path) -> None:
    missing = sorted({path for path in TEST_PATH.findall(page.read_text()) if not (ROOT / path).is_file()})
    assert missing == [], f"{page.relative_to(ROOT)} names test files that do not exist: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_selection_a_page_names_finds_a_test_in_its_file(page: Path) -> None:
    """``pytest PATH -k WORD`` with one word selects the tests whose name holds it (ignoring case): the file
    must define one, or the test moved and the page still sends readers to its old home."""
    empty = []
    for path, word in SELECTION.findall(page.read_text()):
        file = ROOT / path
        names = re.findall(r"^\s*(?:async )?def (test_\w+)", file.read_text(), re.M) if file.is_file() else []
        if not any(word.lower() in name.lower() for name in names):
            empty.append(f"{path} -k {word}")
    assert empty == [], f"{page.relative_to(ROOT)} names selections that find no test: {empty}"


def test_the_test_path_patterns() -> None:
    text = "`pytest tests/video/test_resample.py -k\nkeeps_every_sample`, `tests/reference.py`, a/tests/b.py"
    assert TEST_PATH.findall(text) == ["tests/video/test_resample.py", "tests/reference.py"]
    assert SELECTION.findall(text) == [("tests/video/test_resample.py", "keeps_every_sample")]


def test_every_subpackage_face_has_an_api_page() -> None:
    """docs/conf.py writes one API page per subpackage it lists (from the face's ``__all__``); every
    subpackage is listed, and every page is in the API index."""
    tree = ast.parse((DOCS / "conf.py").read_text())
    (listed,) = [
        ast.literal_eval(node.value)
        for node in tree.body
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "SUBPACKAGES" for t in node.targets)
    ]
    package = ROOT / "anra_torch"
    faces = {p.parent.name for p in package.glob("*/__init__.py")}
    assert {name for name, _ in listed} == faces
    index = (DOCS / "api" / "index.md").read_text()
    assert [name for name, _ in listed if not re.search(rf"^{name}$", index, re.M)] == []
