# Two entry points for a fresh machine with Python 3.11 and make: `make demo`, `make test`.
# Each creates (or reuses) .venv and installs veil into it; nothing depends on the host.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.veil-installed
JOBS   ?= 2
# compiled engine code (JAX's persistent compilation cache) stays in the checkout too
export VEIL_CACHE_DIR ?= $(CURDIR)/.veil-cache

.PHONY: demo test bench warmup venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -n $(JOBS) -q

demo: $(STAMP)
	$(VENV)/bin/veil demo -o demo-out

# compile and store the engine programs ahead of time (veil warmup; docs/performance.md)
warmup: $(STAMP)
	$(VENV)/bin/veil warmup

bench: $(STAMP)
	$(PY) benchmarks/bench_apparent.py

clean:
	rm -rf $(VENV) demo-out .pytest_cache .veil-cache
