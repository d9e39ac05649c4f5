# The two set-up commands of the README: `make demo` and `make test`.
# Both install everything they need into the current Python (3.11+) first.
# torch==2.13.0 is installed on its own first: any other torch requirement that pip
# resolves by itself may download a CUDA build of several GB.
PYTHON ?= python3
PIP := $(PYTHON) -m pip install --quiet --disable-pip-version-check

.PHONY: install demo test bench

install:
	$(PIP) torch==2.13.0
	$(PIP) -e ".[all,test]"

demo: install
	$(PYTHON) -m spotlights demo --out out/demo

test: install
	$(PYTHON) -m pytest -q

bench: install
	$(PYTHON) benchmarks/encode.py
