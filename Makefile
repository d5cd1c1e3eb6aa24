# cgp_sim — the two commands are `make run` and `make test`; `make test` runs `make setup` first, `make run` too but
# on a fresh clone only the default scene's kernels (see `run`).
#
# Set-up is incremental: every slow step leaves a stamp in .venv/.stamps and reruns only when its inputs
# change (requirements files -> pip; msgs_config/cgp_sim_msgs, msgs_config/upstream/<pkg> -> cmake, each interface
# package rebuilt only when a hash of its own inputs changed; setup.py and the data files -> pip install -e .; the
# Python sources -> their bytecode and the kernels' warm-up).
# The upstream copies (tf2_msgs, simulation_interfaces) are built only where no installed package of that name
# exists (tools/build_msgs.py says which it uses).

SHELL := /bin/bash
# The interpreter the venv is made from (the ROS wheels are CPython 3.11's): the distribution's own python3.11 where
# there is one with venv, else python3 from PATH.  Debian's is built with profile-guided and link-time optimization
# and its interpreter links its core statically; pyenv's default build does neither (a shared libpython, no PGO).
# numba compiles the kernels in Python: 6-9 % less compile CPU on Debian's (the solver's and the contacts' compile
# workers, four interleaved pairs), the default scene's step ~8 % faster, the 100-hull pile's the same (issue 34).
# `make distclean` first to move an existing venv; `make setup PYTHON=python3.11` picks another.
DISTRIBUTION_PYTHON := /usr/bin/python3.11
ifeq ($(origin PYTHON),undefined)
PYTHON := $(if $(shell $(DISTRIBUTION_PYTHON) -c 'import ensurepip, venv' 2>/dev/null && echo yes),$(DISTRIBUTION_PYTHON),python3)
endif

# The ROS 2 distribution: Jazzy (the product's target, CI's) in .venv/; `make test ROS_DISTRO=kilted` runs the
# optional second target in .venv-kilted/.  Only a ROS_DISTRO given on the make command line counts: a sourced
# ROS install exports ROS_DISTRO too, and that must not switch the wheels this Makefile installs.
DISTRO := $(if $(filter command line,$(origin ROS_DISTRO)),$(ROS_DISTRO),jazzy)
ifeq ($(DISTRO),jazzy)
VENV := $(CURDIR)/.venv
ROS_REQUIREMENTS := requirements/ros.txt requirements/build.txt
else ifeq ($(DISTRO),kilted)
VENV := $(CURDIR)/.venv-kilted
ROS_REQUIREMENTS := requirements/ros-kilted.txt requirements/build-kilted.txt
else
$(error ROS_DISTRO=$(DISTRO) is not supported: use jazzy (default) or kilted)
endif
VPY := $(VENV)/bin/python
STAMPS := $(VENV)/.stamps
# Every install is constrained by the lock (tools/lock_requirements.py): a fresh machine installs what CI tested.
CONSTRAINTS := requirements/constraints-$(DISTRO).txt
PIP := $(VPY) -m pip install --disable-pip-version-check --quiet -c $(CONSTRAINTS)

# What `make run` passes to the node; override e.g. `make run ARGS="--scene pyramid"`.
BAG_DIR ?= $(CURDIR)/bags/cgp_sim_$(shell date +%Y_%m_%d-%H_%M_%S)
ARGS ?=

MSGS_TOOLS := tools/build_msgs.py tools/rosidl_python_only.cmake
MSGS_SRC := $(shell find msgs_config/cgp_sim_msgs -type f -not -path '*/__pycache__/*') $(MSGS_TOOLS)
TF2_MSGS_SRC := $(shell find msgs_config/upstream/tf2_msgs -type f) $(MSGS_TOOLS)
SIMULATION_INTERFACES_SRC := $(shell find msgs_config/upstream/simulation_interfaces -type f) $(MSGS_TOOLS)
# The project is installed editable (the venv imports the checkout): pip reruns only for setup.py's own inputs,
# tools/install_data_files.py for the data files it lists (the ament layout), the warm-up for any Python source.
PROJECT_SRC := setup.py setup.cfg package.xml README.md resource/cgp_sim_ros scripts/sim_node \
	tools/install_data_files.py $(wildcard msgs_config/scenes/*.yaml msgs_config/params/*.yaml \
	msgs_config/sweeps/*.yaml msgs_config/foxglove/*.json msgs_config/meshes/*.stl msgs_config/meshes/*.obj)
KERNEL_SRC := $(shell find cgp_core cgp_sim_ros -type f -name '*.py' -not -path '*/__pycache__/*')
REQUIREMENTS := $(ROS_REQUIREMENTS) requirements/python.txt requirements/dev.txt

.PHONY: setup run test soak fuzz bench figures lock clean distclean

# (One step after the other.  The interface packages' build side by side with the kernels' compile — a sub-make
# -j2, neither needs the other — was measured slower on a fresh clone on 2 cores: cmake 52 -> 107 s, the kernels
# 143 -> 213 s, set-up 277 -> 312 s; both already use every core.)
setup: $(STAMPS)/kernels

$(STAMPS)/venv:
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "cgp_sim needs Python >= 3.11 (found " + sys.version.split()[0] + "); set PYTHON=python3.11")'
	@command -v cmake >/dev/null || { echo "cgp_sim needs cmake (apt install cmake) to build its interface package"; exit 1; }
	@test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	@mkdir -p $(STAMPS) && touch $@

$(STAMPS)/deps: $(REQUIREMENTS) $(CONSTRAINTS) | $(STAMPS)/venv
	@echo "setup: installing ROS 2 wheels and Python dependencies into .venv (pip)"
	@$(PIP) $(addprefix -r ,$(REQUIREMENTS)) 2> >(grep -v 'is ignored: it is neither a file nor a directory' >&2)
	@touch $@

# The interface packages: ours (cgp_sim_msgs) and ROS 2 Jazzy's tf2_msgs and simulation_interfaces, which have no
# wheel (our byte-identical copies, built unless the environment has them), in one call that builds side by side
# only what rclpy loads (no C++), and only the packages whose inputs changed (a content hash per package in
# $(STAMPS)/msgs-<package>.sha256): ~1 min for the three on 2 cores the first time (docs/development.md).
$(STAMPS)/msgs: $(STAMPS)/deps $(MSGS_SRC) $(TF2_MSGS_SRC) $(SIMULATION_INTERFACES_SRC)
	@echo "setup: building the interface packages (cgp_sim_msgs; tf2_msgs and simulation_interfaces unless installed)"
	@$(VPY) tools/build_msgs.py --stamps $(STAMPS)
	@touch $@

# Editable: the venv's cgp_core, cgp_sim_ros and msgs_config are the checkout's, so the node, the tests (which
# import the checkout) and the compile workers share one numba cache (the checkout's __pycache__), and no
# installed copy can fall behind an edit.  pip -e installs no data_files: tools/install_data_files.py puts
# setup.py's (the ament layout ros2 run and ament_index_python resolve) into the venv.
$(STAMPS)/project: $(STAMPS)/msgs $(PROJECT_SRC)
	@echo "setup: installing cgp_sim (cgp_core, cgp_sim_ros, msgs_config) into .venv, editable"
	@$(PIP) --no-deps --no-build-isolation -e . 2> >(grep -v 'is ignored: it is neither a file nor a directory' >&2)
	@rm -rf build cgp_sim_ros.egg-info
	@$(VPY) tools/install_data_files.py
	@touch $@

# The sources' bytecode: an editable install gets none from pip, and where PYTHONDONTWRITEBYTECODE is set (this
# machine kind's shells, CI's) no import writes it either, so every process (each node start, each test's node,
# each compile worker) compiled the project's ~110 modules from source again: ~0.3 s of every start, measured.
# compileall writes it whatever that variable says; an edited source is compiled again (its .pyc is then stale).
$(STAMPS)/bytecode: $(STAMPS)/project $(KERNEL_SRC)
	@$(VPY) -m compileall -q -j 0 cgp_core cgp_sim_ros msgs_config
	@touch $@

$(STAMPS)/kernels: $(STAMPS)/bytecode $(KERNEL_SRC)
	@echo "setup: compiling the simulation kernels (numba, cached: only after an install or an edit)"
	@$(VPY) -m cgp_sim_ros.warmup
	@touch $@

# The default scene's kernels alone (its three compile workers, ~30 s on a fresh clone), for `make run`.
$(STAMPS)/kernels-default: $(STAMPS)/bytecode $(KERNEL_SRC)
	@echo "setup: compiling the default scene's kernels (numba, cached: only after an install or an edit)"
	@$(VPY) -m cgp_sim_ros.warmup --default-scene
	@touch $@

# The live view is on (the node prints the address to open in the Foxglove app); ARGS="--foxglove false" turns
# it off, ARGS="--foxglove-port 0" picks a free port.
# Before a set-up has compiled every kernel (a fresh clone), `make run` compiles the default scene's only, not every
# kernel (~140 s) that a first run would wait for; a scene of hulls or robots has the node compile the rest at its
# start (cgp_sim_ros.warmup.compile_missing_kernels).  Once `make setup` or `make test` has, every kernel again
# after an edit, as before.
run: $(if $(wildcard $(STAMPS)/kernels),$(STAMPS)/kernels,$(STAMPS)/kernels-default)
	@$(VENV)/bin/cgp-sim --bag "$(BAG_DIR)" --foxglove true $(ARGS)

# The tests import the checkout, which is the installed package (editable): `make setup`'s warm-up compiled
# their kernels, once, in parallel worker processes, so that no test compiles them one by one inside its own
# time limit.
# Two pytest-xdist workers (TEST_WORKERS=1 for one process): most of the suite's wall time is tests waiting on
# node processes, which two workers overlap; each worker's nodes live in a ROS domain of their own
# (tests/conftest.py).  Files are the unit of distribution, so a module's shared node starts once; the longest
# first (tests/conftest.py: pytest_collection_modifyitems), so that no long file is left for the end.
TEST_WORKERS ?= 2
test: setup
	@$(VPY) -m pytest tests $(if $(filter-out 1,$(TEST_WORKERS)),-n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder)

# The soak test (tests/test_soak.py) runs CGP_SIM_SOAK_SECONDS of wall time (default 900); it is read from the
# environment: `CGP_SIM_SOAK_SECONDS=60 make soak` or `make soak CGP_SIM_SOAK_SECONDS=60` (issue 27's one-hour
# run: `make soak CGP_SIM_SOAK_SECONDS=3600`).
soak: setup
	@$(VPY) -m pytest tests -m soak --run-soak -rA  # -rA: show the figures the soak test prints

# Issue 27's fuzzing (tests/test_fuzz_inputs.py: the scene/spawn parser, mesh files, the command decoders, the
# Foxglove client-message path, the renderer's marker reader) with FUZZ_EXAMPLES fresh random examples per property
# (`make test` runs a few dozen fixed ones): `make fuzz FUZZ_EXAMPLES=5000`.  A failure prints the smallest
# input it found and the blob to reproduce it (@reproduce_failure).  The kernels run with numba's bounds checks
# (NUMBA_BOUNDSCHECK=1, issue 38: an index out of bounds is an IndexError, not memory corrupted), compiled into a
# cache of their own (numba's cache does not tell the two builds apart), first in the warm-up's workers: ~5 min
# the first time.
FUZZ_EXAMPLES ?= 2000
FUZZ_CACHE := $(VENV)/numba-boundscheck
fuzz: setup
	@NUMBA_BOUNDSCHECK=1 NUMBA_CACHE_DIR=$(FUZZ_CACHE) $(VPY) -m cgp_sim_ros.warmup
	@NUMBA_BOUNDSCHECK=1 NUMBA_CACHE_DIR=$(FUZZ_CACHE) FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) $(VPY) -m pytest \
		tests/test_fuzz_inputs.py -p no:cacheprovider --timeout=0 -q --hypothesis-show-statistics

# Re-resolve the requirement files (and the benchmark peers) into the lock; commit the result.
lock: | $(STAMPS)/venv
	@$(VPY) tools/lock_requirements.py $(DISTRO) $(REQUIREMENTS) requirements/bench.txt requirements/figures.txt

bench: setup
	@$(PIP) -r requirements/bench.txt 2> >(grep -v 'is ignored: it is neither a file nor a directory' >&2)
	@$(VPY) benchmarks/run.py

# Issue 14's figures (README): Couzin et al. 2002's phases and hysteresis loop (the built-in sweep
# couzin_hysteresis run by cgp-sim-sweep on a LocalCluster, one worker per core, into sweeps/: ~3 min of CPU; with
# the dt = 1/60 s rate check, the sweep couzin_rate_check) and the predator's fountain effect.  Resumable: a
# finished run is never run again.  FIGURE_ARGS="--seeds 4" for a quicker, coarser sweep;
# `benchmarks/figures/couzin_sweep.py --plot-only` redraws from the sweep's tables in sweeps/.
FIGURE_ARGS ?= --rate-check
figures: setup
	@$(PIP) -r requirements/figures.txt 2> >(grep -v 'is ignored: it is neither a file nor a directory' >&2)
	@$(VPY) benchmarks/figures/predator_run.py
	@$(VPY) benchmarks/figures/couzin_sweep.py $(FIGURE_ARGS)

clean:
	rm -rf build *.egg-info .pytest_cache
	find . -name __pycache__ -type d -prune -not -path './.venv/*' -exec rm -rf {} +

distclean: clean
	rm -rf $(CURDIR)/.venv $(CURDIR)/.venv-kilted
