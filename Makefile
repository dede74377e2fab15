# Quick start:  make demo   (set up .venv, run the demo)      make test   (set up .venv, run the tests)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test test-fast lint bench clean clean-cache

# torch comes from the machine's CPU wheel first, so that nothing pulls a CUDA build
$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check torch==2.13.0
	$(PY) -m pip install --quiet --disable-pip-version-check -e '.[all]'
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m catmip_env.demo --out out/demo

test: $(STAMP)
	$(PY) -m pytest -n 2 tests

test-fast: $(STAMP)
	$(PY) -m pytest -n 2 -m "not slow" tests

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

bench: $(STAMP)
	$(PY) benchmarks/bench_engine.py
	$(PY) benchmarks/bench_events.py
	$(PY) benchmarks/bench_amat.py
	$(PY) benchmarks/bench_train.py

# numba keys each cached kernel on its own file only: after editing a kernel that others call, drop the cache
clean-cache:
	find . -path ./$(VENV) -prune -o \( -name '*.nbi' -o -name '*.nbc' \) -exec rm -f {} +

clean:
	rm -rf $(VENV) out .pytest_cache .hypothesis
	find . -name __pycache__ -prune -exec rm -rf {} +
