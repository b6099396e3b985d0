# The two set-up commands of the README (`make demo`, `make test`), plus the inner loop.
# Each creates .venv if missing and installs into it.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-fast lint typecheck layout bench clean browser

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

# --no-compile: pip would byte-compile every module of every dependency, most of which nothing
# imports; Python compiles the ones imported as they first load
$(STAMP): pyproject.toml setup.py | $(BIN)/python
	$(BIN)/python -m pip install --quiet --no-compile -e '.[test]'
	touch $(STAMP)

# The real path: a sample capture folder (written from the simulator into demo/capture), ingested
# into demo/run.zarr, processed by the btf flow, reported (demo/run-report/index.html).
demo: $(STAMP)
	$(BIN)/spectralize demo --capture demo/capture

# Lint, types and the whole suite, as CI runs it (.ci/run): one pytest worker per core (a test
# module stays on one worker, so its fixtures are built once; the longest modules are handed out
# first, in the order tests/conftest.py gives them, not xdist's), then the tests marked `timing`
# (they assert on wall time or an ETA) alone, so that no other test's load skews them. Each
# pass ends with its slowest tests (setup, call and teardown apart): where the time goes.
# The second pass collects only the modules that mark tests `timing` (collecting the whole
# suite to select a few would cost as much as running them; tests/test_markers.py checks
# that no timing test lives elsewhere).
PYTEST_WORKERS ?= auto
PYTEST_DURATIONS ?= 40
TIMING_MODULES = $(shell grep -rl --include='test_*.py' 'mark\.timing' tests)
test: lint typecheck browser
	$(BIN)/python -m pytest -n $(PYTEST_WORKERS) --dist loadfile --no-loadscope-reorder -m "not timing" --durations=$(PYTEST_DURATIONS)
	$(BIN)/python -m pytest -m timing --durations=$(PYTEST_DURATIONS) $(TIMING_MODULES)

# The inner loop: the suite without the tests marked `slow` (real flows, killed processes,
# the wheel install); about a third of the time.
test-fast: $(STAMP)
	$(BIN)/python -m pytest -n $(PYTEST_WORKERS) --dist loadfile --no-loadscope-reorder -m "not slow and not timing"
	$(BIN)/python -m pytest -m "timing and not slow" $(TIMING_MODULES)

# A real headless browser for the report's test (tests/flows/test_report.py takes a screenshot):
# Debian's chromium-headless-shell, installed only when no Chromium is there (PyPI has no
# browser build that installs offline; Playwright downloads its own).
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
browser:
	@command -v chromium-headless-shell >/dev/null 2>&1 || command -v chromium >/dev/null 2>&1 || \
	  { $(SUDO) apt-get update -qq && \
	    $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium-headless-shell; }

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[bench]'
	$(BIN)/python benchmarks/reconstruction.py
	$(BIN)/python benchmarks/calibration.py
	$(BIN)/python benchmarks/btf_flow.py
	$(BIN)/python benchmarks/cli.py

# import-linter and mypy find packages by folder, so they read the rooms through a folder of links
# with the installed layout: build/layout/spectralize/<room> -> <room> (every top-level folder
# that is a package is a room, as in setup.py).
LAYOUT := build/layout
layout:
	@rm -rf $(LAYOUT) && mkdir -p $(LAYOUT)/spectralize
	@cp spectralize/__init__.py spectralize/py.typed $(LAYOUT)/spectralize/
	@for init in */__init__.py; do room=$${init%/__init__.py}; \
	  [ "$$room" = spectralize ] || ln -s ../../../$$room $(LAYOUT)/spectralize/$$room; done

# Style and import rules: formatting, lint, and the import contracts in pyproject.toml
# (schemas <- store <- engine <- nodes <- datasets <- flows; only flows imports Prefect; nodes do
# not open the store; no stage imports the simulator; no import cycles).
lint: $(STAMP) layout
	$(BIN)/ruff format --check .
	$(BIN)/ruff check .
	cd $(LAYOUT) && PYTHONPATH=. ../../$(BIN)/lint-imports ../../pyproject.toml --no-cache

# Static types of the rooms every other one builds on, and of the reconstruction (mypy settings
# in pyproject.toml).
typecheck: $(STAMP) layout
	MYPYPATH=$(LAYOUT) $(BIN)/mypy -p spectralize.schemas -p spectralize.store -p spectralize.engine \
	  -p spectralize.nodes.reconstruction

clean:
	rm -rf demo build .pytest_cache .mypy_cache
