# Two commands for a newcomer: `make demo` and `make test`.
# Both create .venv when it is missing and install the project into it first.

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
REFERENCE := $(VENV)/.numba-reference
export MPLBACKEND := Agg
export SDL_VIDEODRIVER := dummy
export PYGAME_HIDE_SUPPORT_PROMPT := 1
# numpy/scipy on small matrices: threads only spin and contend (see estimators notes)
export OPENBLAS_NUM_THREADS := 1
export OMP_NUM_THREADS := 1

.PHONY: demo test lint bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

# dist (ray, a 79 MB wheel) is installed so the Ray backend's equivalence test runs on
# every commit, not only on machines where someone installed ray by hand.
# torch first and pinned: a local CPU wheel of 2.13.0 satisfies the `torch>=2.2` range
# below, so pip never fetches another (multi-GB) build.
# Then the C ports are built where a C compiler is at hand and the kernels compiled
# into numba's on-disk cache, split across the cores and each once: the first identify,
# demo or test run loads them instead of compiling (a job that fails is reported and
# only means its kernels compile at first use).
$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e ".[dev,rl,plot,render,dist]"
	-$(BIN)/python -m manualcontrol.bench.compile_kernels
	touch $(STAMP)

# Where the C ports run, the numba kernels they replace are only the tests' reference
# (the tests compare the two bit for bit): compiled here, once, before the workers
# start, and never waited for by the demo.
$(REFERENCE): $(STAMP)
	-$(BIN)/python -m manualcontrol.bench.compile_kernels --numba-reference
	touch $(REFERENCE)

demo: $(STAMP)
	$(BIN)/python -m manualcontrol.bench.demo

# one pytest worker a core (pytest-xdist); a test file stays on one worker, so its
# module fixtures (simulated runs) are built once. `pytest tests/...` alone runs serially.
test: $(STAMP) $(REFERENCE)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -n auto --dist loadfile

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

clean:
	rm -rf $(VENV) results .pytest_cache
