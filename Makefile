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

# The browser page's npm packages and the browser driver of its tests (tests/test_web.py), as locked.
NODE_STAMP := node_modules/.package-lock.json
$(NODE_STAMP): package-lock.json
	npm ci --no-audit --no-fund

# Test files run in parallel (one process per core, at most 4); each file stays in one process, so a
# module's expensive fixture (an MJX compile, a clean venv) is built once.
TEST_JOBS ?= $(shell $(PYTHON) -c "import os; print(min(4, os.cpu_count() or 1))")

test: $(STAMP) $(NODE_STAMP)
	$(PY) -m pytest -q -n $(TEST_JOBS) --dist loadfile tests

lint: $(STAMP)
	$(PY) -m ruff check .

train: $(STAMP)
	$(PY) experiments/ppo_cartpole.py --logdir=runs/ppo_cartpole --eval_every=20000

bench: $(STAMP)
	$(PY) bench/throughput.py

clean:
	rm -rf $(VENV) runs
