# dpos workspace.
#   make demo    bootstrap .venv if needed (runtime: requirements.txt), run the end-to-end demo (.venv/bin/dpos-demo)
#   make test    bootstrap .venv if needed (runtime + dev tools), run the linters (make lint; mypy beside the tests) and the test suite (pytest)
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
# What pip installs is byte-compiled (needed: with PYTHONDONTWRITEBYTECODE set, as on the CI
# machine, Python would otherwise compile every module it imports from source in every process it
# starts; measured: the test suite 979 -> ~1300 s) - not by pip, which compiles file by file on one
# core (half of a fresh install's time), but afterwards on every core, without the packages' own
# test suites, which nothing imports (requirements.txt into a new venv: 60 s -> 32 + 8 s).
PIP_INSTALL := $(VPY) -m pip install --no-compile
VENV_NOT_COMPILED := [/\\]tests?[/\\]
COMPILE_VENV := $(VPY) -m compileall -q -j 0 -x '$(VENV_NOT_COMPILED)' $(VENV)/lib
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
RUFF := $(VENV)/bin/ruff check --no-cache src tools bench test
MYPY := $(VENV)/bin/mypy --cache-dir $(VENV)/.mypy_cache $(foreach p,$(PACKAGES),-p $(p))

export PIP_DISABLE_PIP_VERSION_CHECK := 1
# ROS 2 middleware of the wheels; DDS discovery stays on this machine.
# (ROS_DOMAIN_ID for tests is chosen per test session by test/conftest.py.)
export RMW_IMPLEMENTATION := rmw_fastrtps_cpp
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: demo test stress lint bench venv clean distclean lock

demo: $(STAMP)
	@$(COMPILE_SRC)
	$(VENV)/bin/dpos-demo

# Every test in one session on every core, with one pytest-xdist worker more than cores (each
# worker has its own ROS_DOMAIN_ID): the graph tests wait on paced real time for part of their run,
# and the extra worker fills it (2 cores: 803 -> 745 s for the suite). The ROS tests (marker `ros`:
# nodes, DDS, timing) run beside CPU-bound ones, as on a busy aircraft computer - they wait on
# conditions, not on an idle machine (make stress adds a CPU burner). ruff first; mypy runs beside
# the tests (its minute of CPU on a fresh clone mostly fills the same gaps) and its findings fail
# make test at the end. Exit status 5 (nothing selected, e.g. PYTEST_ARGS names no test) is not a failure.
PYTEST_WORKERS ?= $(shell echo $$(( $$(nproc) + 1 )))
test: $(DEV_STAMP)
	$(RUFF)
	@$(COMPILE_SRC)
	@echo "$(MYPY) (beside the tests; its output after them)"
	@$(MYPY) > $(VENV)/mypy.log 2>&1 & mypy=$$!; \
	$(VPY) -m pytest -q -n $(PYTEST_WORKERS) --dist loadgroup --durations=20 $(PYTEST_ARGS); rc=$$?; [ $$rc -ne 5 ] || rc=0; \
	wait $$mypy; mrc=$$?; cat $(VENV)/mypy.log; \
	if [ $$mrc -ne 0 ]; then echo "make test: mypy found errors (above)"; exit 1; fi; exit $$rc

# The ROS tests on a busy machine: STRESS_BURNERS CPU-bound processes run beside them for the whole
# session (test/conftest.py --cpu-burner; stopped at its end, and they exit by themselves if pytest dies).
STRESS_BURNERS ?= 1
stress: $(DEV_STAMP)
	@$(COMPILE_SRC)
	@echo "loadavg before: $$(cut -d' ' -f1-3 /proc/loadavg)"
	$(VPY) -m pytest -q -m ros --cpu-burner $(STRESS_BURNERS) --durations=15 $(PYTEST_ARGS) || [ $$? -eq 5 ]

lint: $(DEV_STAMP)
	$(RUFF)
	$(MYPY)

BENCH_STAMP := $(VENV)/.dpos-bench-installed

bench: $(BENCH_STAMP)
	$(VPY) bench/run_bench.py

$(BENCH_STAMP): $(STAMP) requirements-bench.txt
	$(PIP_INSTALL) -qq -c requirements.txt -r requirements-bench.txt
	@$(COMPILE_VENV)
	@touch $@

venv: $(DEV_STAMP)

# --use-pep517: install the editable packages through a PEP 660 wheel, so that the console
# scripts land in .venv/bin (see the comment in src/*/setup.cfg).
$(STAMP): requirements.txt $(PACKAGE_META)
	@test -x $(VPY) || { echo "creating $(VENV)"; $(PYTHON) -m venv $(VENV); }
	@echo "installing requirements.txt into $(VENV) (about a minute on a fresh venv)"
	$(PIP_INSTALL) -qq -r requirements.txt
	@# the workspace's packages (pip and setuptools on one core) while the libraries are compiled (on
	@# the others; the editable finders pip writes meanwhile are left out of that pass)
	@$(VPY) -m compileall -q -j 0 -x '$(VENV_NOT_COMPILED)|__editable__' $(VENV)/lib & compile=$$!; \
	$(PIP_INSTALL) -q --no-deps --no-build-isolation --use-pep517 $(foreach p,$(PACKAGES),-e src/$(p)); rc=$$?; \
	wait $$compile || rc=1; exit $$rc
	@$(VPY) -m compileall -q $(VENV)/lib/python*/site-packages/__editable__*.py
	@touch $@

$(DEV_STAMP): $(STAMP) requirements-dev.txt
	@echo "installing requirements-dev.txt into $(VENV) (test and lint tools, dpos_ros[campaign])"
	$(PIP_INSTALL) -qq -c requirements.txt -r requirements-dev.txt
	@$(COMPILE_VENV)
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
