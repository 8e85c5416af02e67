# sb3-trpo-plus: every target sets itself up (virtualenv + CPU torch) on a fresh machine.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
ENV ?= Grasper3D-v7
ALGO ?= trpo_plus
STEPS ?=
SEED ?= 0
export MUJOCO_GL ?= egl

.PHONY: install test test-fast lint type train docs bench wheel-check clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip
	# CPU build of torch first (a local wheel); a later range that 2.13.0 satisfies installs nothing more
	$(BIN)/pip install "torch==2.13.0"
	$(BIN)/pip install -e ".[test,zoo,docs,ray,bench]"
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	$(BIN)/pytest -n 2 -q

test-fast: $(STAMP)
	$(BIN)/pytest -n 2 -q -m "not slow"

lint: $(STAMP)
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

type: $(STAMP)
	$(BIN)/mypy

train: $(STAMP)
	$(BIN)/trpo-plus main --env $(ENV) --algo $(ALGO) --seed $(SEED) $(if $(STEPS),--steps $(STEPS),)

docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

bench: $(STAMP)
	$(BIN)/python -m benchmarks.speed
	$(BIN)/python -m benchmarks.scaling

# Build the sdist and wheel, install the wheel into a clean virtualenv and run it from outside the checkout
wheel-check: $(STAMP)
	BUILD_PYTHON=$(BIN)/python PYTHON=$(PYTHON) .ci/wheel_check.sh

clean:
	rm -rf $(VENV) site .pytest_cache .mypy_cache .ruff_cache
