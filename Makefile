# Two commands for a fresh machine (no ROS installation needed):
#   make run    start the node on the default scene with the Foxglove live view on port
#               FOXGLOVE_PORT (8765; 0: off) (ARGS='--ros-args -p alpha:=0.9' passes on)
#   make test   run the whole test suite
# Each creates .venv (ROS 2 Jazzy client libraries as Python wheels, numpy, numba, ...) if it
# is missing and reinstalls only when setup.py or package.xml changes. The node compiles
# the solver kernels its scene needs when it starts (seconds, once: Numba's on-disk cache)
# and the rest in a background process; `make test` compiles them all first
# (python -m sm_ros.warmup), then runs the suite in two worker processes (pytest-xdist:
# each its own ROS domain). `make lint` checks every Python file with ruff (configured in
# pyproject.toml) and that the files generated from the parameter table are up to date.

PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed-stamp
ARGS ?=
PYTEST_ARGS ?=
FOXGLOVE_PORT ?= 8765

.PHONY: run test lint venv clean

venv: $(STAMP)

$(STAMP): setup.py setup.cfg package.xml
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet -e '.[ros,viz,record,progress,test]'
	touch $(STAMP)

run: $(STAMP)
	@if [ "$(FOXGLOVE_PORT)" != "0" ]; then \
	  echo "Live view: open Foxglove (https://app.foxglove.dev or the desktop app), 'Open connection'," \
	       "Foxglove WebSocket, ws://localhost:$(FOXGLOVE_PORT)"; fi
	$(VENV)/bin/sim_node --ros-args -p foxglove.port:=$(FOXGLOVE_PORT) $(ARGS)

test: $(STAMP)
	$(VENV)/bin/python -m sm_ros.warmup
	$(VENV)/bin/python -m pytest -q test -n 2 $(PYTEST_ARGS)

lint: $(STAMP)
	$(VENV)/bin/python -m ruff check .
	$(VENV)/bin/python -m sm_ros.params --check

clean:
	rm -rf $(VENV) build install log .pytest_cache
