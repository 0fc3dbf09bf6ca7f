# Two commands do everything on a fresh machine: `make reproduce` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: reproduce test lint format install clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

# PyTorch for the reference learner (extra `rl`): the CPU build from this machine's disk
# (pip's find-links), never a download: a plain torch requirement would take a CUDA build
# of several GB. Where the file is not on disk, no torch: its tests are skipped.
TORCH  ?= 2.13.0

# The rest with uv, which pip installs into the venv first: it resolves and installs these
# packages in about 5 s where pip takes about 50 s here (docs/performance.md). With torch
# already installed, uv keeps it (the extra asks for a range). Where uv cannot be had, or
# fails (it reads no pip.conf: a machine whose packages come from a mirror pip is set up
# for), pip installs them instead, the same way.
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet "uv>=0.4" || true
	if $(BIN)/python -m pip install --quiet --no-index --no-deps "torch==$(TORCH)" 2>/dev/null; \
	then extras="dev,envs,rl"; \
	else echo "no CPU build of torch $(TORCH) on disk: installing without the rl extra"; \
	extras="dev,envs"; fi; \
	if $(BIN)/python -m uv --version >/dev/null 2>&1 && \
	$(BIN)/python -m uv pip install --quiet --python $(BIN)/python -e ".[$$extras]"; \
	then :; else echo "no uv, or uv failed: installing with pip"; \
	$(BIN)/python -m pip install --quiet -e ".[$$extras]"; fi
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
