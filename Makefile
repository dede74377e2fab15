# Quick start:  make demo   (set up .venv, run the demo)      make test   (set up .venv, run the tests)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DSTAMP := $(VENV)/.installed-distributed

.PHONY: demo demo-env test test-slow test-distributed test-compat-lower lint api bench bench-quick bench-peer dist clean clean-cache

# torch comes from the machine's CPU wheel first, so that nothing pulls a CUDA build
$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check torch==2.13.0
	$(PY) -m pip install --quiet --disable-pip-version-check -e '.[all,dev]'
	touch $(STAMP)

# the distributed extra (ray) on top of the same .venv
$(DSTAMP): $(STAMP)
	$(PY) -m pip install --quiet --disable-pip-version-check -e '.[all,distributed]'
	touch $(DSTAMP)

# train AMAT for a few minutes on Task 1, evaluate it (and the shipped model) against the planners
# DEMO_ARGS: e.g. "--threads 1" on a machine that is already busy (see the README)
demo: $(STAMP)
	$(PY) -m catmip_rl.cli.demo --out out/demo $(DEMO_ARGS)

# the planners only (no torch needed): the catmip_env demo
demo-env: $(STAMP)
	$(PY) -m catmip_env.demo --out out/demo-env

# the contributor's loop: every test but the long ones (marked slow) and Ray's
test: $(STAMP)
	$(PY) -m pytest -n 2 -m "not slow and not ray" tests

# the long ones: training runs, whole-episode sweeps, entry replays (CI runs them too)
test-slow: $(STAMP)
	$(PY) -m pytest -n 2 -m "slow and not ray" tests

# Ray: the collector and the benchmark's runner against a local Ray cluster on loopback
test-distributed: $(DSTAMP)
	$(PY) -m pytest -m ray tests

# the lowest torchrl / tensordict the rl extra allows, in a venv of its own: the tests that touch TorchRL
# (env, actor, PPO loss, GAE, PettingZooWrapper, the MAPPO example; not Ray): ~1.5 min from scratch, ~30 s after.
LOWER_VENV ?= .venv-lower
LOWER_PY   := $(LOWER_VENV)/bin/python
LOWER_PINS ?= torchrl==0.14.0 tensordict==0.14.2
TORCHRL_TESTS := tests/rl/adapters/test_torchrl_env.py tests/rl/training/test_collect.py tests/rl/adapters/test_actor_checkpoint.py tests/rl/training/test_ppo.py \
	tests/rl/training/test_gae.py tests/env/test_pettingzoo_macro.py::test_torchrl_check_env_specs \
	tests/test_examples.py::test_mappo_torchrl_trains_saves_and_evaluates_through_its_factory \
	tests/test_examples.py::test_mappo_torchrl_resumes_from_its_last_save \
	tests/test_examples.py::test_mappo_torchrl_resumes_from_its_weights_only_snapshot \
	tests/test_examples.py::test_mappo_torchrl_starts_from_a_saved_policy_with_a_critic_warmup \
	tests/rl/adapters/test_torchrl_marl.py tests/rl/evaluation/test_user_policy.py

test-compat-lower:
	test -x $(LOWER_PY) || $(PYTHON) -m venv $(LOWER_VENV)
	$(LOWER_PY) -m pip install --quiet --disable-pip-version-check torch==2.13.0
	$(LOWER_PY) -m pip install --quiet --disable-pip-version-check -e '.[all,dev]'
	$(LOWER_PY) -m pip install --quiet --disable-pip-version-check $(LOWER_PINS)
	$(LOWER_PY) -c "import torchrl, tensordict; print('torchrl', torchrl.__version__, 'tensordict', tensordict.__version__)"
	$(LOWER_PY) -m pytest -m "not ray" $(TORCHRL_TESTS)

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

# the API reference, generated from the docstrings (pdoc): docs/api/index.html
api: $(STAMP)
	$(PY) docs/build_api.py --out docs/api

# every benchmark, JSON per benchmark + benchmarks/results/SUMMARY.md and summary.png (bench-quick: short settings)
bench: $(STAMP)
	$(PY) benchmarks/run_all.py

bench-quick: $(STAMP)
	$(PY) benchmarks/run_all.py --quick

# the env beside POGEMA 1.4.0, its closest grid-MARL peer: POGEMA pins gymnasium 0.28, which PettingZoo
# cannot share, so it gets a venv of its own (never a dependency of catmip); ~3 minutes
PEER_VENV ?= .venv-pogema
bench-peer: $(STAMP)
	test -x $(PEER_VENV)/bin/python || $(PYTHON) -m venv $(PEER_VENV)
	$(PEER_VENV)/bin/python -m pip install --quiet --disable-pip-version-check 'pogema==1.4.0'
	$(PY) benchmarks/bench_peer.py --pogema-python $(PEER_VENV)/bin/python

# the release: dist/catmip-VERSION.tar.gz and the wheel built from that sdist (python -m build, in an
# isolated environment with setuptools from the index); tests/test_wheel.py installs such a wheel in a
# clean venv and runs the env alone, then the rl extra
dist: $(STAMP)
	rm -rf dist
	$(PY) -m build --outdir dist .
	ls -l dist

# drop numba's compiled kernels (the packages already do when their sources change: catmip_env/runtime/numba_cache.py)
clean-cache:
	find . -path ./$(VENV) -prune -o \( -name '*.nbi' -o -name '*.nbc' \) -exec rm -f {} +

clean:
	rm -rf $(VENV) out dist build .pytest_cache .hypothesis
	find . -name __pycache__ -prune -exec rm -rf {} +
