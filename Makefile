# Two commands set everything up on a fresh machine (each creates .venv itself):
#   make demo   install penfree and run deform -> verify -> report on a bundled sample
#   make test   install penfree with its test extras and run the whole test suite
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
SAMPLE ?= samples/cloth.h5
OUT    ?= demo-out

.PHONY: demo test test-all bench clean clean-cache help

help:
	@echo "make demo      deform + verify + report on $(SAMPLE) (output in $(OUT)/)"
	@echo "make test      run the test suite (creates $(VENV))"
	@echo "make test-all  also the slow tests (full CCD benchmark)"
	@echo "make bench     run the benchmark scripts (installs ipctk)"

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# One stamp per set of extras, so that demo and test share one environment.
$(VENV)/.stamp-plots: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[plots]'
	@touch $@

$(VENV)/.stamp-test: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $@

$(VENV)/.stamp-bench: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test,bench]'
	@touch $@

demo: $(VENV)/.stamp-plots
	@mkdir -p $(OUT)
	$(BIN)/penfree info $(SAMPLE)
	$(BIN)/penfree deform $(SAMPLE) -o $(OUT)/deformed.h5 --stats --overwrite
	$(BIN)/penfree verify $(OUT)/deformed.h5
	$(BIN)/penfree report $(OUT)/deformed.h5 -o $(OUT)/report --overwrite
	@echo
	@echo "demo done: $(OUT)/deformed.h5, $(OUT)/report/report.md"

test: $(VENV)/.stamp-test
	$(BIN)/python -m pytest -q

test-all: $(VENV)/.stamp-test
	$(BIN)/python -m pytest -q -m "slow or not slow"

bench: $(VENV)/.stamp-bench
	$(BIN)/python benchmarks/bench_fit.py
	$(BIN)/python benchmarks/bench_verify.py
	$(BIN)/python benchmarks/bench_bounds.py

# Numba's on-disk cache is invalidated per source file only: after editing a kernel
# that other modules' kernels call (e.g. core/distance.py), clear it.
clean-cache:
	find penfree -name '*.nbi' -delete -o -name '*.nbc' -delete

clean: clean-cache
	rm -rf $(VENV) $(OUT) .pytest_cache .hypothesis
