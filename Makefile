# Every target sets itself up: a .venv made here, torch installed deliberately, the package editable.
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
# CPU build by default (this is what a fresh CI machine needs). GPU users: install their own torch
# into .venv first (or set TORCH_SPEC / TORCH_INDEX); an importable torch is never replaced.
TORCH_SPEC ?= torch==2.13.0
TORCH_INDEX ?=
STAMP := $(VENV)/.installed

DATASET ?= invertedpendulum/medium-v0
STEPS ?= 6000
SEED ?= 0
OUT ?= outputs/main
PYTEST_ARGS ?=
# one torch thread by default (as docs/benchmarks.md's figures); e.g. BENCH_ARGS="--device cuda" on a GPU
BENCH_ARGS ?= --threads 1

.PHONY: install train test test-all lint format type bench bench-quick score peers clean

install: $(STAMP)

$(VENV)/bin/python:
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(STAMP): setup.py $(VENV)/bin/python
	@$(PY) -c "import torch" 2>/dev/null && echo "torch already installed: $$($(PY) -c 'import torch; print(torch.__version__)')" \
		|| $(PY) -m pip install -q "$(TORCH_SPEC)" $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX),)
	$(PY) -m pip install -q -e ".[zoo,tests,dev]"
	@touch $(STAMP)

train: $(STAMP)
	$(PY) -m sb3_pola.cli run --dataset $(DATASET) --steps $(STEPS) --seed $(SEED) --out $(OUT)

test: $(STAMP)
	OMP_NUM_THREADS=1 $(PY) -m pytest tests -n 2 -m "not slow" --timeout 600 $(PYTEST_ARGS)

test-all: $(STAMP)
	OMP_NUM_THREADS=1 $(PY) -m pytest tests -n 2 --timeout 1800 $(PYTEST_ARGS)

lint: $(STAMP)
	$(PY) -m ruff check sb3_pola tests experiments
	$(PY) -m ruff format --check sb3_pola tests experiments
	$(VENV)/bin/lint-imports
	@for f in $$(git ls-files 'experiments/*.sh'); do bash -n "$$f" || exit 1; done
	@# no module over 600 lines (#24)
	@find sb3_pola -name '*.py' -exec wc -l {} + | awk '$$2 != "total" && $$1 > 600 {print "over 600 lines: " $$2 " (" $$1 ")"; bad = 1} END {exit bad}'

format: $(STAMP)
	$(PY) -m ruff format sb3_pola tests experiments
	$(PY) -m ruff check --fix sb3_pola tests experiments

type: $(STAMP)
	$(PY) -m mypy sb3_pola

bench: $(STAMP)
	$(PY) -m sb3_pola.cli bench --out benchmarks/results $(BENCH_ARGS)

bench-quick: $(STAMP)
	$(PY) -m sb3_pola.cli bench --quick --out benchmarks/results $(BENCH_ARGS)

score: $(STAMP)
	$(PY) -m sb3_pola.cli score $(SCORE_ARGS)

# d3rlpy baselines into score's folder (table.md gets them); d3rlpy lives in its own venv, made on first use
PEERS_ARGS ?=
peers: $(STAMP)
	$(PY) -m sb3_pola.cli peers $(PEERS_ARGS)

clean:
	rm -rf $(VENV) .venv-peers build dist *.egg-info .pytest_cache .mypy_cache .ruff_cache outputs
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
