# Two commands on a fresh machine with Python 3.11+ and make: `make demo` and `make test` (and `make docs`).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-xla-defaults test-slow lint typecheck bench docs clean

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "seaice_jax needs Python 3.11 or newer")'
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/seaice demo

# The tests in parallel processes, one per core (at most 4), a test file per process: each process runs XLA with one
# thread (tests/conftest.py), so a single process would leave the other cores idle.
TEST_WORKERS ?= auto

test: $(STAMP)
	OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -q -n $(TEST_WORKERS) --maxprocesses=4 --dist loadfile --durations=15

# The numerical core again with XLA's default CPU code generation (the suite compiles with XLA's classic emitters,
# the faster to compile: tests/conftest.py). In .ci/run.
CORE_TESTS := tests/test_engine.py tests/test_lsq.py tests/test_nist.py tests/test_range_doppler.py tests/test_scan.py

test-xla-defaults: $(STAMP)
	XLA_FLAGS= OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -q -n $(TEST_WORKERS) --maxprocesses=4 --dist loadfile $(CORE_TESTS)

# The end-to-end runs and the repeats at scale (Dask clusters, concurrent and interrupted commands, Monte Carlo of
# hundreds of realizations, whole workflows of the docs, the demo): minutes each; in .ci/run after `make test`.
test-slow: $(STAMP)
	OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -q -m slow -n $(TEST_WORKERS) --maxprocesses=4 --dist loadfile --durations=15

lint: $(STAMP)
	$(VENV)/bin/ruff check .

typecheck: $(STAMP)
	$(VENV)/bin/pyright

bench: $(STAMP)
	$(PY) benchmarks/bench_geometry.py
	$(PY) benchmarks/bench_orbit_fit.py
	$(PY) benchmarks/bench_block.py
	$(PY) benchmarks/bench_remap.py
	$(PY) benchmarks/bench_nist.py
	$(PY) benchmarks/bench_sequence_block.py
	$(PY) benchmarks/bench_sentinel1.py
	$(PY) benchmarks/bench_cli.py
	$(PY) benchmarks/bench_memory.py

# The documentation site (mkdocs.yml, docs/): built into site/ with every warning an error. Its tools (the `docs`
# extra) are installed into .venv on first use.
DOCS_STAMP := $(VENV)/.docs-installed

$(DOCS_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e '.[test,docs]'
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet

clean:
	rm -rf seaice-demo site .pytest_cache
