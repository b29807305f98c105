# `make study` and `make test` set up .venv on a fresh machine by themselves.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= runs/default

.PHONY: setup study test test-fast claims lint clean

setup: $(STAMP)

# torch is pinned first so that the project's `torch>=` range resolves to the local CPU wheel
# instead of pulling a multi-GB CUDA build from PyPI's default index.
# uv installs the same versions as pip in 8 s instead of 51 on a fresh machine. It does not compile bytecode up front
# (that took 15-35 s, for every module of torch, ray and the rest); instead the commands below unexport
# PYTHONDONTWRITEBYTECODE, so that the first process to import a module writes its bytecode and every later one
# (pytest's workers, the CLI's and Ray's subprocesses) reads it: 10-17 s once, for the modules actually imported. On the machine
# where up-front compiling took 15 s, a fresh clone's `make test` took the same either way (3:49 against 3:52). uv does
# not read pip's configuration, so pip's wheel folders are passed on. Where uv cannot be installed or cannot reach an
# index, pip does it all as before.
unexport PYTHONDONTWRITEBYTECODE
# Python's string hashing is salted per process unless PYTHONHASHSEED is set, and a study's figures can depend on it
# (one of paper Town5's 96 offline drives at seed 10 parts at its 85th step under another salt; where it enters was not
# found: docs/study.md). Every process these targets start (the CLI's pool and Ray workers inherit it) hashes alike.
export PYTHONHASHSEED := 0
WHEELS ?= $(or $(PIP_FIND_LINKS),$(wildcard /opt/wheels))
UV := $(BIN)/uv pip install -q --python $(BIN)/python $(foreach w,$(WHEELS),--find-links $(w))
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	($(BIN)/pip install -q uv && $(UV) torch==2.13.0 && $(UV) -e ".[dev,ray]") || \
	  ($(BIN)/pip install -q --upgrade pip && $(BIN)/pip install -q torch==2.13.0 && $(BIN)/pip install -q -e ".[dev,ray]")
	touch $(STAMP)

study: $(STAMP)
	OMP_WAIT_POLICY=PASSIVE $(BIN)/pernav study --preset default --out $(OUT) --workers 2 --resume

# every test and every module's doctests (the target is 7 minutes from a fresh clone on 2 cores: 3:49 on a 2-core AMD
# EPYC, of which 8 s set-up; 7:25-7:39 on an earlier, slower 2-core machine with up-front compiling).
# One torch thread per pytest worker:
# two workers on two cores, instead of torch's default of one thread per core in each
test: $(STAMP)
	OMP_NUM_THREADS=1 OMP_WAIT_POLICY=PASSIVE $(BIN)/python -m pytest -q -n 2 --dist load --maxschedchunk 2 --doctest-modules tests pernav

# the inner loop: everything but the tests marked slow (75 s on the 2-core development machine; the target is 90 s)
test-fast: $(STAMP)
	OMP_NUM_THREADS=1 OMP_WAIT_POLICY=PASSIVE $(BIN)/python -m pytest -q -n 2 --dist loadfile -m "not slow" --doctest-modules tests pernav

# the frozen world's claims that take dozens of whole episodes (recipes/claims: explore completes its routes, the oracle
# beats it for atypical users; 2 min, 3.2 CPU-minutes). CI runs them after `make test`; run them after any change to
# pernav/world
claims: $(STAMP)
	OMP_NUM_THREADS=1 OMP_WAIT_POLICY=PASSIVE $(BIN)/python -m pytest -q -n 2 recipes/claims

# docs/paper.md's generated section, docs/paper/fig3.png and regret.png from docs/paper/results/*.json (seconds)
.PHONY: paper
paper: $(STAMP)
	$(BIN)/python -m recipes.benchmarks.paper --build

lint: $(STAMP)
	$(BIN)/ruff check pernav recipes tests docs/research/scripts

clean:
	rm -rf $(VENV)
