# The two set-up commands of the README: `make demo` and `make test`.
# Both install everything they need first, into the Python chosen here (3.11+), on every system:
#   1. PYTHON=... on the command line: that interpreter (e.g. make test PYTHON=python3);
#   2. inside an active virtual environment or conda environment: its python3;
#   3. otherwise a project environment .venv, created on first use (`python3 -m venv .venv`) and
#      used by every later make command: nothing is installed into the system's or pyenv's Python.
# torch==2.13.0 is installed on its own first: any other torch requirement that pip resolves by
# itself may download a CUDA build of several GB.
SYSTEM_PYTHON ?= python3
VENV ?= .venv

ifndef PYTHON
ifeq ($(VIRTUAL_ENV)$(CONDA_PREFIX),)
PYTHON := $(VENV)/bin/python
MAKE_VENV := $(VENV)/bin/python
endif
endif
PYTHON ?= python3
PIP := $(PYTHON) -m pip install --quiet --disable-pip-version-check

.PHONY: install demo test bench lint format where gpu-bundle

install: $(MAKE_VENV)
	$(PIP) torch==2.13.0
	$(PIP) -e ".[all,test]"

$(VENV)/bin/python:
	@echo "creating the project environment $(VENV) with '$(SYSTEM_PYTHON) -m venv' (PYTHON=... or an active environment to use another)"
	@$(SYSTEM_PYTHON) -m venv $(VENV) || { rm -rf $(VENV); echo "make: could not create $(VENV) with '$(SYSTEM_PYTHON) -m venv' (on Debian/Ubuntu: apt install python3-venv)" >&2; exit 1; }

demo: install
	$(PYTHON) -m spotlights demo --out out/demo

# Two test processes (pytest-xdist; one torch thread each, tests/conftest.py), whole files to one process
# (module fixtures run once): the suite keeps one core busy, so this uses the second of a 2-core machine.
# `python -m pytest` alone runs the same tests in one process.
test: install
	$(PYTHON) -m pytest -q -n 2 --dist loadfile --max-worker-restart 0

bench: install
	$(PYTHON) benchmarks/encode.py

# Lint and format (ruff; configured in pyproject.toml; installed by the test extra). `make test` runs
# the same checks (tests/test_style.py: ruff check and ruff format --check), so CI enforces them.
lint:
	$(PYTHON) -m ruff check .

format:
	$(PYTHON) -m ruff format .
	$(PYTHON) -m ruff check --fix .

# Which interpreter the commands above use, and why.
where:
	@echo "PYTHON=$(PYTHON) ($(if $(MAKE_VENV),the project environment $(VENV); made from $(SYSTEM_PYTHON),$(if $(VIRTUAL_ENV)$(CONDA_PREFIX),the active environment $(VIRTUAL_ENV)$(CONDA_PREFIX),given on the command line)))"

# The GPU recipe's bundle (docs/learning.md, "GPU recipe"): the project's wheel, the wheels of the packages a GPU
# machine without internet may lack (never torch) and the car meshes, into .whl/ (git-ignored) for
# scripts/gpu_train.sh there.
gpu-bundle: install
	PYTHON=$(PYTHON) scripts/gpu_bundle.sh
