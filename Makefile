# dpos workspace.
#   make demo    bootstrap .venv if needed (runtime: requirements.txt), run the end-to-end demo (.venv/bin/dpos-demo)
#   make test    bootstrap .venv if needed (runtime + dev tools), run the linters (make lint) and the test suite (pytest)
#   make stress  the ROS tests (marker `ros`) with one CPU-bound process beside them (STRESS_BURNERS=1)
#   make lint    ruff (ruff.toml) and mypy (mypy.ini) on the sources; part of make test
#   make venv    bootstrap .venv for development (runtime + requirements-dev.txt), as make test does
#   make bench   bootstrap .venv if needed, run the benchmarks (writes bench/results.json)
#   make clean   remove build artefacts;  make distclean  also remove .venv
#   make lock    re-resolve requirements*.txt from requirements*.in (tools/lock_requirements.py)

SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
VPY := $(VENV)/bin/python
# pip byte-compiles what it installs (half of a fresh install's time, but needed: with
# PYTHONDONTWRITEBYTECODE set, as on the CI machine, Python would otherwise compile every module it
# imports from source in every process it starts; measured: the test suite 979 -> ~1300 s).
PIP_INSTALL := $(VPY) -m pip install
# The same for the workspace's own modules (installed editable, so pip compiles none of them): every
# node, command and worker process of a test run or the demo would compile them again from source
# (about 0.3 s of CPU per process, hundreds of processes per test run). Up-to-date files are skipped.
COMPILE_SRC := $(VPY) -m compileall -q -j 0 src test/support
# The venv is (re)installed when this stamp is older than the lock or any package's metadata.
STAMP := $(VENV)/.dpos-installed
# The dev tools (pytest, ruff, mypy, ...) and the campaign extra (dask, distributed), on top.
DEV_STAMP := $(VENV)/.dpos-dev-installed
PACKAGES := dpos_core dpos_ros pos_master_node pos_sub_node ifa_node transfer_align_node sar_nav_node
PACKAGE_META := $(foreach p,$(PACKAGES),src/$(p)/setup.py src/$(p)/setup.cfg src/$(p)/package.xml)
PYTEST_ARGS ?=

export PIP_DISABLE_PIP_VERSION_CHECK := 1
# ROS 2 middleware of the wheels; DDS discovery stays on this machine.
# (ROS_DOMAIN_ID for tests is chosen per test session by test/conftest.py.)
export RMW_IMPLEMENTATION := rmw_fastrtps_cpp
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: demo test stress lint bench venv clean distclean lock

demo: $(STAMP)
	@$(COMPILE_SRC)
	$(VENV)/bin/dpos-demo

# Every test in one session on both cores (pytest-xdist; each worker has its own ROS_DOMAIN_ID):
# the ROS tests (marker `ros`: nodes, DDS, timing) run beside CPU-bound ones, as on a busy aircraft
# computer - they wait on conditions, not on an idle machine (make stress adds a CPU burner).
# Exit status 5 (nothing selected, e.g. PYTEST_ARGS names no test) is not a failure.
PYTEST_WORKERS ?= 2
test: lint
	@$(COMPILE_SRC)
	$(VPY) -m pytest -q -n $(PYTEST_WORKERS) --dist loadgroup --durations=20 $(PYTEST_ARGS) || [ $$? -eq 5 ]

# The ROS tests on a busy machine: STRESS_BURNERS CPU-bound processes run beside them for the whole
# session (test/conftest.py --cpu-burner; stopped at its end, and they exit by themselves if pytest dies).
STRESS_BURNERS ?= 1
stress: $(DEV_STAMP)
	@$(COMPILE_SRC)
	@echo "loadavg before: $$(cut -d' ' -f1-3 /proc/loadavg)"
	$(VPY) -m pytest -q -m ros --cpu-burner $(STRESS_BURNERS) --durations=15 $(PYTEST_ARGS) || [ $$? -eq 5 ]

MYPY_PACKAGES := $(foreach p,$(PACKAGES),-p $(p))

lint: $(DEV_STAMP)
	$(VENV)/bin/ruff check --no-cache src tools bench test
	$(VENV)/bin/mypy --cache-dir .venv/.mypy_cache $(MYPY_PACKAGES)

BENCH_STAMP := $(VENV)/.dpos-bench-installed

bench: $(BENCH_STAMP)
	$(VPY) bench/run_bench.py

$(BENCH_STAMP): $(STAMP) requirements-bench.txt
	$(PIP_INSTALL) -qq -c requirements.txt -r requirements-bench.txt
	@touch $@

venv: $(DEV_STAMP)

# --use-pep517: install the editable packages through a PEP 660 wheel, so that the console
# scripts land in .venv/bin (see the comment in src/*/setup.cfg).
$(STAMP): requirements.txt $(PACKAGE_META)
	@test -x $(VPY) || { echo "creating $(VENV)"; $(PYTHON) -m venv $(VENV); }
	@echo "installing requirements.txt into $(VENV) (about a minute on a fresh venv)"
	$(PIP_INSTALL) -qq -r requirements.txt
	$(PIP_INSTALL) -q --no-deps --no-build-isolation --use-pep517 $(foreach p,$(PACKAGES),-e src/$(p))
	@touch $@

$(DEV_STAMP): $(STAMP) requirements-dev.txt
	@echo "installing requirements-dev.txt into $(VENV) (test and lint tools, dpos_ros[campaign])"
	$(PIP_INSTALL) -qq -c requirements.txt -r requirements-dev.txt
	@touch $@

clean:
	rm -rf build install log .pytest_cache
	rm -rf $(foreach p,$(PACKAGES),src/$(p)/build src/$(p)/$(p).egg-info)
	find src test bench tools -name __pycache__ -type d -prune -exec rm -rf {} + 2>/dev/null || true

distclean: clean
	rm -rf $(VENV)

# requirements.txt first: the other two are resolved with it as constraints (their `-c requirements.txt`).
lock:
	$(PYTHON) tools/lock_requirements.py requirements.in requirements.txt
	$(PYTHON) tools/lock_requirements.py requirements-dev.in requirements-dev.txt --on-top-of requirements.txt
	$(PYTHON) tools/lock_requirements.py requirements-noros.in requirements-noros.txt
