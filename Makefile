# Two commands: `make run` (set up, then run the quick suite and print its table) and `make test`.
# Setup is idempotent: system packages only when missing, pip only when pyproject.toml changed.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export DRJIT_LIBLLVM_PATH ?= /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1

.PHONY: setup sysdeps run test bench lint clean baseline variability

setup: sysdeps $(STAMP)

sysdeps:
	@bash scripts/sysdeps.sh

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# The third-party method plugin (plugins/plantbench-pcskeletor) is part of the setup: the scan suite lists it. Its
# tool, pc-skeletor, is installed without its declared dependencies (they would replace open3d-cpu; see its README).
$(STAMP): pyproject.toml plugins/plantbench-pcskeletor/pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[test,cluster,thirdparty]'
	$(BIN)/python -m pip install -q --no-deps pc-skeletor==1.0.0
	@touch $(STAMP)

run: setup
	$(BIN)/plantbench run --suite quick --out runs --workers 2

# The tests, then the quick suite end to end, gated against the committed baseline (CI runs this).
test: setup
	$(BIN)/python -m pytest -q tests plugins/plantbench-pcskeletor/tests
	$(BIN)/plantbench run --suite quick --out runs --workers 2
	$(BIN)/plantbench gate runs/quick --baseline reports/baseline.json

bench: setup
	$(BIN)/python -m pytest -q bench --benchmark-only --benchmark-columns=min,mean,median,rounds

# Re-make the gate's baseline and its tolerances together (after an intended change in accuracy; commit
# reports/baseline.json, reports/tolerances.json and reports/variability/): the variability study below.
baseline: variability

# The variability study: the quick suite under perturbations that carry no meaning (Dr.Jit target and vector width,
# +-1 grey level of image noise, thread count, the methods' input cloud shuffled or moved by 1e-6 m, OpenBLAS's and
# numpy's own kernels in place of the pins); writes reports/tolerances.json, reports/baseline.json and
# reports/variability/ (commit them).
variability: setup
	$(BIN)/plantbench variability --suite quick --out runs/variability --reports reports

lint: setup
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) runs .pytest_cache .benchmarks
