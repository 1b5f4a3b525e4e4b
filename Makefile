# Every target bootstraps its own .venv: a fresh clone needs only `make test` or `make train`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
export MENAGERIE_ROOT ?= $(if $(wildcard ../shared/robots),$(abspath ../shared/robots),)

.PHONY: install test lint train bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[dev]"
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q tests

lint: $(STAMP)
	$(PY) -m ruff check .

train: $(STAMP)
	$(PY) experiments/ppo_cartpole.py --logdir=runs/ppo_cartpole --eval_every=20000

bench: $(STAMP)
	$(PY) bench/throughput.py

clean:
	rm -rf $(VENV) runs
