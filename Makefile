# The two set-up commands of the README. Each creates .venv if missing and installs into it.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench lint clean browser

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# The real path: a sample capture folder (written from the simulator into demo/capture), ingested
# into demo/run.zarr, processed by the btf flow, reported (demo/run-report/index.html).
demo: $(STAMP)
	$(BIN)/spectralize demo --capture demo/capture

test: lint browser
	$(BIN)/python -m pytest

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

# Style and import rules: formatting, lint, and the import contracts in pyproject.toml
# (schemas <- engine <- nodes <- flows; only flows imports Prefect; no stage imports simulation).
lint: $(STAMP)
	$(BIN)/ruff format --check .
	$(BIN)/ruff check .
	$(BIN)/lint-imports

clean:
	rm -rf demo .pytest_cache
