# Two commands do all set-up on a fresh machine: `make demo` and `make test`; `make docs` builds the site.
VENV    ?= .venv
PY      := $(VENV)/bin/python
# --no-compile: pip would compile all ~11,600 modules of the environment to bytecode (~26 CPU-s of a ~53 CPU-s
# install); `make test` instead writes bytecode for the ~2,800 the tests import, on their first import
# (PYTHONDONTWRITEBYTECODE= overrides a machine-wide 1, which would otherwise make every process compile them).
PIP     := $(PY) -m pip install -q --no-compile -c constraints.txt
BYTECODE := PYTHONDONTWRITEBYTECODE=
STAMP   := $(VENV)/.anra-installed
DOCS_STAMP := $(VENV)/.anra-docs-installed
LINT_STAMP := $(VENV)/.anra-lint-installed
OUT     ?= results/demo

.PHONY: demo test test-fast install lint docs bench-paper clean

$(PY):
	python3 -m venv $(VENV)

# Re-install only when the package metadata changes. One pip call: constraints.txt pins torch's CPU build, so a
# separate torch install first only paid pip's start-up and resolution twice (the same environment either way).
$(STAMP): pyproject.toml constraints.txt | $(PY)
	$(PIP) -e ".[test,plot,peers,formats,parquet,dask]"
	touch $(STAMP)

install: $(STAMP)

$(DOCS_STAMP): $(STAMP)
	$(PIP) -e ".[docs]"
	touch $(DOCS_STAMP)

# The documentation site, offline and strict: a warning (a broken link, a reference to a name that is not
# documented at its face, a docstring that is not valid markup) fails it; not yet nitpicky (-n). From scratch each time (-E: no stale pages).
docs: $(DOCS_STAMP)
	$(VENV)/bin/sphinx-build -E -q -W --keep-going -b html docs docs/_build/html
	@echo "docs/_build/html/index.html"

demo: $(STAMP)
	$(VENV)/bin/anra demo --out $(OUT)

test: $(STAMP)
	$(BYTECODE) $(PY) -m pytest -q -n 2 --dist worksteal

test-fast: $(STAMP)
	$(BYTECODE) $(PY) -m pytest -q -n 2 --dist worksteal -m "not slow"

$(LINT_STAMP): $(STAMP)
	$(PIP) -e ".[lint]"
	touch $(LINT_STAMP)

# ruff (lint and format) and mypy over the package, pinned in pyproject's `lint` extra; CI runs it first.
lint: $(LINT_STAMP)
	$(VENV)/bin/ruff check anra_torch tests experiments benchmarks
	$(VENV)/bin/ruff format --check anra_torch tests experiments benchmarks
	$(VENV)/bin/mypy

bench-paper: $(STAMP)
	$(PY) -m experiments.paper_simulation --out results/paper_simulation

clean:
	rm -rf $(VENV) results .pytest_cache docs/_build
