# Two commands do all the set-up: `make demo` and `make test`. Each creates .venv when it is
# missing (or when pyproject.toml or constraints.txt changed): torch first, pinned to the CPU build
# on this machine's disk, so that the project's own `torch` requirement pulls nothing more; then
# the project, every other package at the version constraints.txt names.

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test clean

$(STAMP): pyproject.toml constraints.txt
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
