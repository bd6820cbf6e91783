# One command each: `make test` (set up, then pass the tests), `make run` (set up, then run the cell).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
UV := $(VENV)/bin/uv
STAMP := $(VENV)/.installed
TMP := $(CURDIR)/.test-tmp

# Nothing depends on the caller's ROS environment: logs and ROS home inside the checkout,
# Fast DDS on loopback only (config/fastdds_loopback.xml; discovery left to that profile, as
# LOCALHOST would make rmw_fastrtps add a transport on every interface; docs/howto/network.md),
# the venv as the ament prefix. Bytecode written (PYTHONDONTWRITEBYTECODE emptied, as a shell
# may set it): the package is installed editable, so without its __pycache__ every process
# would compile the modules it imports again, 0.1-0.15 s of each node's start.
RUN_ENV := ROS_LOG_DIR=$(TMP)/ros_log ROS_HOME=$(TMP)/ros_home \
	FASTRTPS_DEFAULT_PROFILES_FILE=$(CURDIR)/config/fastdds_loopback.xml \
	ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT ROS_LOCALHOST_ONLY= \
	AMENT_PREFIX_PATH=$(CURDIR)/$(VENV) MPLBACKEND=Agg PYTHONDONTWRITEBYTECODE=

.PHONY: test test-library setup clean bench run docs

setup: $(STAMP)

# The typed interfaces (actions, services): a second ROS package, built from its own folder by
# scikit-build-core against the ROS 2 wheels into the venv prefix (nothing to source; about a
# minute the first time, then reused), and by colcon on a ROS install (docs/howto/building.md).
# tf2_msgs (for /tf and /tf_static), which the PyPI wheels lack, is built the same way from its
# Jazzy definitions, only where it is not importable already; a ROS install uses its own.
INTERFACES := interfaces/positioning_cell_interfaces
TF2_MSGS := interfaces/tf2_msgs
INTERFACE_FILES := interfaces/ros_wheels.cmake $(foreach d,$(INTERFACES) $(TF2_MSGS), \
	$(wildcard $(d)/*.txt $(d)/*.xml $(d)/*.toml $(d)/msg/*.msg $(d)/srv/*.srv $(d)/action/*.action))

# Reinstalls only when the package metadata or the interfaces change; the package itself is
# editable.
$(STAMP): setup.py setup.cfg package.xml $(INTERFACE_FILES)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	test -x $(UV) || $(PY) -m pip install --quiet --disable-pip-version-check uv==0.13.9
	$(UV) pip install --quiet --compile-bytecode --python $(PY) --reinstall-package \
		positioning_cell_interfaces ./$(INTERFACES) -e '.[cell,test]' \
		$$($(PY) -c 'import tf2_msgs.msg' 2>/dev/null || echo ./$(TF2_MSGS))
	# The package's bytecode now (the editable install leaves it to the first import; RUN_ENV
	# lets later imports refresh it), so that the first nodes started do not each compile it.
	$(PY) -m compileall -q positioning_cell
	# Compile the numba kernels once now (cached on disk), not in the first process that needs them.
	$(PY) -c 'from positioning_cell.core import kinematics; kinematics.warm_up()'
	$(PY) -c 'from positioning_cell.tolerance import montecarlo; montecarlo.warm_up()'
	$(PY) -c 'from positioning_cell.limits import axis_ranges; axis_ranges.warm_up()'
	# mypy's incremental cache of the package and of what it imports (numpy's and scipy's
	# stubs: 28 s of CPU cold, 0.4 s warm), where test_code_quality keeps it: make test then
	# checks only what changed since. Its errors are the test's to report, not setup's.
	-$(PY) -m mypy --cache-dir $(TMP)/mypy_cache/package positioning_cell > /dev/null
	touch $(STAMP)

# The suite in three tiers. First the tests that start nodes or processes or take long (markers
# nodes or slow, not timing) in TEST_WORKERS pytest-xdist workers (each node test takes its own
# ROS domain, so they run side by side). Then the tests that judge a reaction time, a stop
# bound or a rate on real processes (marker timing), one at a time, so that the suite's own
# load is not what they measure, with the library tier (none of those markers: no node, no
# process of its own, no clock judged) beside them at idle CPU priority (test/beside.py: Linux
# SCHED_IDLE, which runs only on a core nothing else wants and yields it at once to any other
# process that wakes). The timing tier keeps about one core busy; the library tests fill the
# other, which stood idle while the timing tier ran alone after all the rest (2:10-2:24 of it
# per run; issue 24). The timing tier took 2:15 with the library tier beside it against
# 2:10-2:17 alone; an idle-priority probe beside it was kept off the CPU 0.89 s at most.
# Three workers on two cores for the first tier: its tests wait on their child processes and
# on discovery, and a third worker fills that time (3:39 with 3 workers against 4:28 with 2
# and 3:54 with 4, one run each on the same 2-core VM, issue 24). Each module goes whole to
# one worker: its module fixtures are set up once (3:30 twice against 3:35-3:39 handing out
# single tests, 6:00 of CPU against 7:08-7:35); xdist hands out the modules with the most
# tests first (test/conftest.py LONGEST_FIRST, the longest first, took 4:43 against 4:40 for
# the first tier on Dec 7: its wall time is bound by its CPU). The timing tier in two workers
# of its own took 1:13-1:18 against 2:13 alone, but in one fresh-clone CI of two a `cell move`
# beside test_faults' cell had no answer in 120 s (not understood; test_cli_on_the_cell), and
# one loop of it in four failed test_faults' "tracker killed": the driver's joint states
# silent 0.99 s after the kill, the abort blamed on the driver (the shared-memory stall of
# docs/howto/run.md, gone with shared memory since). Tried again over loopback UDP alone with
# quick repairs (a8cf8e6): the first of five runs failed test_coordinated_cell's stop from
# speed (the panel's attachments 36 um apart against its 20 um bound: the two simulated drives,
# whose timers it judges, did not stop as one beside the second worker's cell). So the timing
# tier has the machine to itself but for what runs at idle priority: what it judges is timing.
# The library tier cannot start beside the node tier as well: at idle priority beside that
# CPU-bound tier it was starved, and four of test_mover's clock-judging tests failed (a move's
# 0.5 s silence bound seen at 0.89 s), while the node tier took 5:38 against 4:52 without it
# (make test on the warm venv, one run each, Dec 7: 9:03 with the failures against 9:15).
TEST_WORKERS ?= 3
NODE_TIER := not timing and (nodes or slow)
LIBRARY_TIER := not timing and not nodes and not slow

test: $(STAMP)
	mkdir -p $(TMP)
	env $(RUN_ENV) $(PY) -m pytest -n $(TEST_WORKERS) --dist loadscope -m '$(NODE_TIER)'
	env $(RUN_ENV) $(PY) test/beside.py -m timing -- -n 2 --dist loadscope -m '$(LIBRARY_TIER)'

# The library tier alone, without ROS: every test not marked nodes or slow, with rclpy made
# unimportable (a stand-in package first on the path that raises ImportError), so a test or a
# module of the library that loads rclpy fails here (test/conftest.py leaves out the modules
# marked nodes or slow without importing them).
NO_ROS := $(TMP)/no_ros
test-library: $(STAMP)
	mkdir -p $(NO_ROS)/rclpy
	printf 'raise ImportError("rclpy is not importable in the library tier (make test-library)")\n' \
		> $(NO_ROS)/rclpy/__init__.py
	env $(RUN_ENV) PYTHONPATH=$(NO_ROS) $(PY) -m pytest -m '$(LIBRARY_TIER)'

# The cell's main job: start the nodes, record, drive config/program.yaml once per compensation
# mode, stop, analyse; results in runs/<timestamp>/. Another program: make run
# PROGRAM=config/acceptance.yaml (or config/accuracy_map.yaml).
PROGRAM ?=
run: $(STAMP)
	mkdir -p $(TMP)
	env $(RUN_ENV) $(PY) -m positioning_cell.tools.run_cell $(if $(PROGRAM),--program $(PROGRAM))

bench: $(STAMP)
	mkdir -p $(TMP)
	for b in benchmarks/*.py; do env $(RUN_ENV) $(PY) $$b || exit 1; done

# The documentation (docs/, Sphinx with MyST Markdown; the reference pages are generated from
# the code): HTML in build/docs. test/test_docs.py builds the same sources with warnings as errors.
docs: $(STAMP)
	mkdir -p $(TMP)
	env $(RUN_ENV) $(VENV)/bin/sphinx-build -W --keep-going -j auto -b html docs build/docs

clean:
	rm -rf $(VENV) $(TMP) build install log $(INTERFACES)/build $(TF2_MSGS)/build docs/api/generated \
		docs/reference/generated
