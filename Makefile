# `make study` and `make test` set up .venv on a fresh machine by themselves.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= runs/default

.PHONY: setup study test lint clean

setup: $(STAMP)

# torch is pinned first so that the project's `torch>=` range resolves to the local CPU wheel
# instead of pulling a multi-GB CUDA build from PyPI's default index.
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e ".[dev,ray]"
	touch $(STAMP)

study: $(STAMP)
	OMP_WAIT_POLICY=PASSIVE $(BIN)/pernav study --preset default --out $(OUT) --workers 2 --resume

test: $(STAMP)
	OMP_WAIT_POLICY=PASSIVE $(BIN)/python -m pytest -q -n 2 tests

lint: $(STAMP)
	$(BIN)/ruff check pernav recipes tests

clean:
	rm -rf $(VENV)
