# The two set-up commands of the README. Each creates .venv if missing and installs into it.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench lint clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/spectralize demo

test: lint
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[bench]'
	$(BIN)/python benchmarks/reconstruction.py
	$(BIN)/python benchmarks/calibration.py
	$(BIN)/python benchmarks/btf_flow.py

# Style and import rules: formatting, lint, and the import contracts in pyproject.toml
# (schemas <- engine <- nodes <- flows; only flows imports Prefect; no stage imports simulation).
lint: $(STAMP)
	$(BIN)/ruff format --check .
	$(BIN)/ruff check .
	$(BIN)/lint-imports

clean:
	rm -rf demo .pytest_cache
