# Two entry points: `make demo` (the light-dark example end to end) and `make test`.
# Each installs only what it needs, with its own stamp: the demo the package alone (its base
# dependencies draw the figures), the tests the package with the test toolchain. `--no-compile`:
# Python compiles the modules it imports on first use instead of pip compiling every file (halves
# the install time of a fresh clone).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
PIP    := $(BIN)/python -m pip install --quiet --disable-pip-version-check --no-compile
DEMO_STAMP := $(VENV)/.installed-demo
TEST_STAMP := $(VENV)/.installed-test

.PHONY: demo test lint bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(DEMO_STAMP): pyproject.toml | $(BIN)/python
	$(PIP) -e .
	touch $(DEMO_STAMP)

$(TEST_STAMP): pyproject.toml | $(BIN)/python
	$(PIP) -e '.[test]'
	touch $(TEST_STAMP)

demo: $(DEMO_STAMP)
	$(BIN)/idstlpy demo light-dark --out out

# The reference tests pin recorded numbers with a tolerance the arithmetic justifies
# (tests/reference_compare.py); they run again under two other OpenBLAS kernel sets, so that a test
# tied to this CPU's kernels fails here first, not on a newcomer's machine (x86-64 only: the core
# types are x86 kernels).
REFERENCE_TESTS := tests/test_prediction_reference.py tests/test_executor_reference.py \
                   tests/test_execute_reference.py tests/test_validate_reference.py

test: $(TEST_STAMP)
	$(BIN)/ruff check src tests benchmarks examples tools
	$(BIN)/ruff format --check src tests benchmarks examples tools
	$(BIN)/mypy src
	$(BIN)/python -m pytest
	@if [ "$$(uname -m)" = x86_64 ]; then \
	  for core in Prescott Haswell; do \
	    echo "reference tests under OPENBLAS_CORETYPE=$$core"; \
	    OPENBLAS_CORETYPE=$$core $(BIN)/python -m pytest $(REFERENCE_TESTS) || exit 1; \
	  done; \
	fi

lint: $(TEST_STAMP)
	$(BIN)/ruff check src tests benchmarks examples tools
	$(BIN)/ruff format --check src tests benchmarks examples tools
	$(BIN)/mypy src
	$(BIN)/python tools/structure_report.py

bench: $(TEST_STAMP)
	$(PIP) -e '.[bench]'
	$(BIN)/python -m benchmarks

clean:
	rm -rf $(VENV) out
