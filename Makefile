# Two commands do all the set-up: `make demo` and `make test`. Each creates .venv when it is
# missing (or when pyproject.toml or constraints.txt changed): torch first, pinned to the CPU build
# on this machine's disk, so that the project's own `torch` requirement pulls nothing more; then
# the project, every other package at the version constraints.txt names. Python 3.11 or newer
# (PYTHON=...; checked on 3.11, 3.12 and 3.13, 2026-12-01).

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test clean

$(STAMP): pyproject.toml constraints.txt
	@test -x $(BIN)/python || $(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "oodmon needs Python 3.11 or newer (rerun-sdk 0.41 and the versions in constraints.txt do); $(PYTHON) is " + sys.version.split()[0] + ": give make another, e.g. make PYTHON=python3.12 demo")'
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/oodmon demo

test: $(STAMP)
	$(BIN)/python -m pytest -q --durations=10 -n auto --dist worksteal

clean:
	rm -rf $(VENV) runs build *.egg-info
