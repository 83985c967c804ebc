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

## test: run the whole test suite (slow tests included), three workers (pytest-xdist), a module each at a time
# Three workers on two cores: much of the suite waits on sockets, child processes and cameras, and
# the third worker fills those waits. One BLAS thread per process: the workers and the services
# they start already fill the cores, and OpenBLAS's idle threads spinning beside them cost time.
# Bytecode is written even where the environment says not to (PYTHONDONTWRITEBYTECODE): the suite
# starts hundreds of Python processes, each of which would compile the package again.
# Then the tests marked `alone` (the load test), by themselves: they measure the service under a
# load they make, which the other workers' tests would add to by an amount nobody chose.
TEST_ENV := PYTHONDONTWRITEBYTECODE= OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
test: $(DEV_STAMP)
	$(TEST_ENV) $(BIN)/python -m pytest -n 3 --dist loadscope --no-loadscope-reorder -m "not alone"
	$(TEST_ENV) $(BIN)/python -m pytest -m alone

## lint: ruff (rules, complexity <= 15, format), mypy --strict, import layering (cli -> service -> rig -> calibration)
lint: $(DEV_STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy calibration rig service cli bench
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV)
