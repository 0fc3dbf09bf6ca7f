# Two commands do everything on a fresh machine: `make reproduce` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: reproduce test lint format install clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev,envs,fast]"
	touch $(STAMP)

install: $(STAMP)

reproduce: $(STAMP)
	$(BIN)/qpatrol reproduce --out results

test: $(STAMP)
	$(BIN)/ruff check qpatrol tests benchmarks examples
	$(BIN)/ruff format --check qpatrol tests benchmarks examples
	$(BIN)/python -m pytest

lint: $(STAMP)
	$(BIN)/ruff check qpatrol tests benchmarks examples

format: $(STAMP)
	$(BIN)/ruff format qpatrol tests benchmarks examples
	$(BIN)/ruff check --fix qpatrol tests benchmarks examples

clean:
	rm -rf $(VENV) results/runs results/scratch .pytest_cache .ruff_cache
