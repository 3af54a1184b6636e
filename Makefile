# Developer entry points. `make demo` and `make test` work on a fresh machine
# with Python 3.11: the first run creates $(VENV) and installs the pinned set.

VENV ?= .venv
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VPY := $(VENV)/bin/python
STAMP := $(VENV)/.pmdc_ident-installed

# Keep every ROS 2 process started from here on this machine: Fast DDS uses
# only the loopback interface (see config/fastdds_localhost.xml) and ROS 2
# discovery stays on localhost, on a fixed domain unless overridden.
ROS_DOMAIN_ID ?= 42
export ROS_DOMAIN_ID
# Fast DDS 2.14 (Jazzy) reads FASTRTPS_DEFAULT_PROFILES_FILE; Fast DDS 3 reads
# FASTDDS_DEFAULT_PROFILES_FILE. Set both.
export FASTDDS_DEFAULT_PROFILES_FILE := $(CURDIR)/config/fastdds_localhost.xml
export FASTRTPS_DEFAULT_PROFILES_FILE := $(FASTDDS_DEFAULT_PROFILES_FILE)
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST

# One BLAS thread per process (pmdc_ident/_blas.py): our matrices are small and on a
# shared machine extra OpenBLAS threads only spin (identify: 2.7 s CPU instead of 1.0 s).
OPENBLAS_NUM_THREADS ?= 1
MKL_NUM_THREADS ?= 1
OMP_NUM_THREADS ?= 1
export OPENBLAS_NUM_THREADS MKL_NUM_THREADS OMP_NUM_THREADS

# Only the paths that exist (benchmarks/ and launch/ may not yet).
LINT_PATHS := $(wildcard pmdc_ident test benchmarks launch examples tools setup.py)
BENCHES := $(sort $(wildcard benchmarks/bench_*.py))

.PHONY: venv demo test lint bench clean

venv: $(STAMP)

# uv (bootstrapped into $(VENV)/uv-bin with pip, outside the venv's packages) downloads
# and unpacks in parallel: a fresh clone's `make venv` took 17-19 CPU-s and 42-72 s wall
# where pip took 35-38 CPU-s and 86-121 s, back to back at load 8-15 (uv's cache empty;
# pip keeps none here). tools/uv_pip.py hands uv the index, mirrors and constraints pip
# is configured for (uv reads no pip.conf); should uv fail anyway, pip installs as
# before. Neither byte-compiles (pip would spend 16 of its 40 CPU-s on it): Python writes
# the .pyc of the ~1,000 modules a run imports the first time it imports them (`make
# test` writes bytecode, see below). The same packages at the same versions, the same
# files (pip freeze --all identical; pip stays in the venv). Re-run only when what it
# installs changes.
UV_VERSION := 0.13.8
UV := $(VENV)/uv-bin/bin/uv
$(STAMP): requirements-dev.txt constraints.txt setup.py setup.cfg
	test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	test -x $(UV) || $(VPY) -m pip install -q --no-compile --target $(VENV)/uv-bin uv==$(UV_VERSION) || true
	$(VPY) tools/uv_pip.py $(UV) install -r requirements-dev.txt -c constraints.txt \
		|| $(VPY) -m pip install --no-compile -r requirements-dev.txt -c constraints.txt
	$(VPY) tools/uv_pip.py $(UV) install -e . --no-deps || $(VPY) -m pip install -e . --no-deps
	test -x $(VENV)/bin/pmdc-ident
	touch $@

demo: $(STAMP)
	$(VPY) -m pmdc_ident.demo

# Two test processes (pytest-xdist): the node tests mostly wait on DDS and the clock,
# the numerics take a core each; each process holds its own DDS domains (test/conftest.py).
# On a fresh clone of this 2-core machine the whole .ci/run took 252-253 s idle and
# 330-346 s beside two CPU hogs (docs/results.md section 9). A third process saved a minute on an
# idle machine of an earlier kind at no more CPU, but cost 170 CPU-s more and timed out a
# DDS service call at load 11-13: `make test TEST_WORKERS=3` on an idle machine if you
# like; `make test TEST_WORKERS=0` runs the suite in one process.
TEST_WORKERS ?= 2

# Bytecode is written even where PYTHONDONTWRITEBYTECODE is set: the suite starts
# hundreds of Python processes (nodes, CLI runs, import probes), and without .pyc files
# each compiled every module of the package it imported again.
test: $(STAMP)
	env -u PYTHONDONTWRITEBYTECODE \
		$(VPY) -m pytest -q test --timeout=600 -n $(TEST_WORKERS) --dist worksteal --durations=15

lint: $(STAMP)
	$(VENV)/bin/ruff check $(LINT_PATHS)
	$(VENV)/bin/ruff format --check $(LINT_PATHS)

bench: $(STAMP)
	@if [ -z "$(BENCHES)" ]; then echo "no benchmarks/bench_*.py yet"; fi
	@set -e; for b in $(BENCHES); do echo "== $$b"; $(VPY) $$b; done

clean:
	rm -rf build install log out .pytest_cache .ruff_cache *.egg-info
	find . -path ./$(VENV) -prune -o -name __pycache__ -type d -print0 | xargs -0 rm -rf
	rm -f $(STAMP)
