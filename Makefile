# Two entry points for a fresh machine with Python 3.11 and make: `make demo`, `make test`.
# Each creates (or reuses) .venv and installs veil into it; nothing depends on the host.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.veil-installed
JOBS   ?= 2
# compiled engine code (JAX's persistent compilation cache) stays in the checkout too
export VEIL_CACHE_DIR ?= $(CURDIR)/.veil-cache

.PHONY: demo test check lint docs bench bench-compile bench-explore browser-deps warmup venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[all,test]'
	@touch $(STAMP)

# --dist worksteal; loadscope (a module's tests on one worker, its module fixtures made once)
# was tried and measured within the host's noise (clean clones, 2 cores: 11:42 and 13:25 of
# tests against worksteal's 12:25 and 13:41), with an idle worker while the last module runs
test: $(STAMP)
	$(PY) -m pytest -n $(JOBS) --dist worksteal -q --durations=30

# the edit-test loop's subset (at most 3 minutes with the program store filled): the layout
# rules, the command line's start and its errors, the compile display, and the model
# contract (declarations, maps, parts, the engine's Jacobian at the fast rule)
CHECK := tests/test_layout.py tests/test_cli_startup.py tests/test_cli_eval.py \
	tests/test_compile_display.py tests/test_model_contract.py tests/test_registry_plugins.py
check: $(STAMP)
	$(PY) -m pytest -n $(JOBS) --dist worksteal -q $(CHECK) \
		-k "not warmup and not brute_force and not monte_carlo and not independent_reference"

# the maintainer's toolbox (pyproject's [tool.ruff] and [tool.mypy]; .pre-commit-config.yaml
# runs the same): ruff's rules over src/, mypy over src/veil, and ruff's format over src/ and
# the test utilities written in its style (FORMATTED_TESTS; the other tests and scripts keep
# their hand-aligned continuation lines until they are next rewritten)
FORMATTED_TESTS := tests/support tests/conftest.py benchmarks/bench_maps_optimistix.py \
	tests/test_ingest_channels.py tests/test_channel_model.py
lint: $(STAMP)
	$(PY) -m ruff check src
	$(PY) -m ruff format --check src $(FORMATTED_TESTS)
	$(PY) -m mypy

# the documentation site (docs/conf.py): warnings are errors, which includes every internal
# link between pages and to a section (MyST's cross-references) and every docstring shown;
# the examples named plot_*.py run and make their figures
DOCS_STAMP := $(VENV)/.veil-docs-installed
$(DOCS_STAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install --quiet -e '.[docs]'
	@touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	rm -rf docs/_build docs/generated docs/auto_examples docs/sg_execution_times.rst
	$(PY) -m sphinx -W --keep-going -q -b html docs docs/_build/html
	@echo "docs/_build/html/index.html"

demo: $(STAMP)
	$(VENV)/bin/veil demo -o demo-out

# compile and store the engine programs ahead of time (veil warmup; docs/performance.md)
warmup: $(STAMP)
	$(VENV)/bin/veil warmup

bench: $(STAMP)
	$(PY) benchmarks/bench_apparent.py

# compile seconds per program and the cold and warm pipeline per registered family pair
bench-compile: $(STAMP)
	$(PY) benchmarks/bench_compile.py

bench-explore: $(STAMP)
	$(PY) benchmarks/bench_explore.py --browser

# What the browser test of `veil explore` needs (tests/test_explore_browser.py): Debian's
# Chromium and its driver, installed as root when missing (CI runs as root).
browser-deps:
	@if command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; then \
		echo "chromium and chromedriver: present"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
			chromium chromium-driver >/dev/null; \
	else \
		echo "the browser test needs chromium and chromium-driver (apt-get install -y chromium chromium-driver as root); it is skipped without them outside CI"; \
	fi

clean:
	rm -rf $(VENV) demo-out .pytest_cache .veil-cache test-artifacts docs/_build docs/generated docs/auto_examples
