# Every target creates or reuses the virtual environment in .venv itself.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
RUN_STAMP := $(VENV)/.installed-run
DEV_STAMP := $(VENV)/.installed-dev

.PHONY: demo test lint venv clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip

$(RUN_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q -e .
	touch $@

$(DEV_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q -e '.[dev]'
	touch $@ $(RUN_STAMP)

venv: $(DEV_STAMP)

## demo: run the depth service on the built-in simulated rig (http://127.0.0.1:8000/)
demo: $(RUN_STAMP)
	$(BIN)/rig serve --demo

## test: run the whole test suite (slow tests included), two workers (pytest-xdist), a module each at a time
test: $(DEV_STAMP)
	$(BIN)/python -m pytest -n 2 --dist loadscope

## lint: ruff (rules, complexity <= 15, format), mypy --strict, import layering (cli -> service -> rig -> calibration)
lint: $(DEV_STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy calibration rig service cli bench
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV)
