# apf_swarm workspace: virtual environment (ROS 2 Jazzy from PyPI wheels) + colcon build.
#
#   make setup      create .venv, install requirements.txt, colcon build into install/
#   make test       setup, then run the tests (extra pytest arguments: PYTEST_ARGS="...",
#                   other paths than test/: TESTS="test/core test/nodes")
#   make run        setup, then the ROS 2 swarm: `apf-swarm up --preset triangle --duration 30
#                   --out runs/<timestamp>` (extra arguments: RUN_ARGS)
#   make reproduce  setup, then `apf-swarm reproduce --out runs/<timestamp>-reproduce`
#   make clean      remove build/ install/ log/        make distclean   ... and .venv/
#
# Every step is skipped when its inputs did not change, so a no-op `make setup` takes a
# fraction of a second. Use `source scripts/activate.sh` for an interactive shell.

SHELL := bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := setup
.DELETE_ON_ERROR:
MAKEFLAGS += --no-print-directory

ROOT := $(abspath $(dir $(lastword $(MAKEFILE_LIST))))
VENV := $(ROOT)/.venv
VPY := $(VENV)/bin/python
# The ROS 2 wheels are built for CPython 3.11 only.
PYTHON ?= $(or $(shell command -v python3.11 2>/dev/null),python3)

REQ_STAMP := $(VENV)/.requirements.stamp
BUILD_STAMP := $(ROOT)/install/.colcon-build.stamp
APF_WRAPPER := $(VENV)/bin/apf-swarm

# What under src/ can affect the build: every file except Python modules and caches, plus each
# package's setup.py, plus src/ and src/<pkg>/ themselves (a package or a top-level entry added
# or removed). Python modules are not listed: with --symlink-install the installed packages are
# symlinks to src/<pkg>/<pkg>/, so edited, added or removed modules take effect without a build.
SRC_FILES := $(shell cd '$(ROOT)' && { find src -maxdepth 1 -type d; \
	find src -mindepth 2 -maxdepth 2 -type f -name setup.py; \
	find src \( -name __pycache__ -o -name '*.egg-info' -o -name '.*_cache' \) -prune \
	  -o -type f ! -name '*.py' ! -name '*.py[co]' ! -name '*.sw?' ! -name '*~' -print; \
	} 2>/dev/null)
# Rebuild when build/ or install/ was removed by hand (symlink-install needs both).
BUILD_FORCE := $(if $(and $(wildcard $(ROOT)/build/COLCON_IGNORE),$(wildcard $(ROOT)/install/setup.bash)),,FORCE)

# A per-invocation DDS domain keeps concurrent runs and tests apart; override on the command
# line (`make test ROS_DOMAIN_ID=7`). A value merely inherited from the environment is not used.
ifneq ($(origin ROS_DOMAIN_ID),command line)
ROS_DOMAIN_ID := $(shell echo $$(( RANDOM % 100 + 1 )))
endif
PYTEST_ARGS ?=
TESTS ?= test
RUN_ARGS ?=
TIMESTAMP := $(shell date +%Y%m%d-%H%M%S)
RUN_DIR ?= runs/$(TIMESTAMP)

# Environment for colcon: only the venv as underlay, never a previously sourced workspace.
COLCON_ENV := env -u PYTHONPATH -u COLCON_PREFIX_PATH -u LD_LIBRARY_PATH \
	-u _ROS_WHEELS_BOOTSTRAP_COMPLETE -u AMENT_CURRENT_PREFIX \
	VIRTUAL_ENV='$(VENV)' PATH='$(VENV)/bin':"$$PATH" \
	AMENT_PREFIX_PATH='$(VENV)' CMAKE_PREFIX_PATH='$(VENV)' PYTHONDONTWRITEBYTECODE=1
COLCON_ARGS := --base-paths src --build-base build --install-base install --symlink-install \
	--cmake-args -DPython3_EXECUTABLE='$(VPY)' -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF

.PHONY: setup warm test run reproduce clean distclean help FORCE

help:
	@sed -n '2,10p' '$(ROOT)/Makefile' | sed 's/^# \{0,1\}//'

setup: $(BUILD_STAMP) $(APF_WRAPPER)

$(VPY):
	@echo "==> creating .venv with $(PYTHON) ($$($(PYTHON) --version 2>&1))"
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' || \
	  { echo "error: the ROS 2 wheels need CPython 3.11; run: make PYTHON=/path/to/python3.11" >&2; exit 1; }
	@$(PYTHON) -m venv '$(VENV)'

$(REQ_STAMP): $(ROOT)/requirements.txt | $(VPY)
	@echo "==> pip install -r requirements.txt (into .venv)"
	@cd '$(ROOT)' && '$(VPY)' -m pip install --disable-pip-version-check --progress-bar off -q \
	  -r requirements.txt 2>&1 | { grep -v 'is ignored: it is neither a file nor a directory' || true; }
	@touch '$@'

$(BUILD_STAMP): $(REQ_STAMP) $(addprefix $(ROOT)/,$(SRC_FILES)) $(ROOT)/Makefile $(BUILD_FORCE)
	@cd '$(ROOT)' && if [ -f '$@' ] && [ '$(REQ_STAMP)' -nt '$@' ]; then \
	  echo "==> requirements changed: removing build/ install/ for a clean build"; rm -rf build install; fi
	@echo "==> colcon build (build/ install/ log/)"
	@cd '$(ROOT)' && $(COLCON_ENV) colcon --log-base log build $(COLCON_ARGS) 2>&1 \
	  | { grep -v "AMENT_PREFIX_PATH doesn't contain any 'local_setup" || true; }
	@$(MAKE) -s warm
	@touch '$@'

# the compiled control kernels into numba's cache, so that no process compiles them at run
# time (seconds once; a fraction of a second when they are current)
warm:
	@echo "==> compiling the control kernels (numba cache)"
	@cd '$(ROOT)' && source scripts/activate.sh && \
	  python -c 'from apf_swarm_core.kernels import warm; warm()'

# `apf-swarm` on PATH without putting lib/apf_swarm_nodes (generic names: target, plant, ...)
# there: a small wrapper in .venv/bin that enters the workspace environment when needed.
$(APF_WRAPPER): $(ROOT)/Makefile | $(REQ_STAMP)
	@printf '%s\n' \
	  '#!/usr/bin/env bash' \
	  '# Generated by `make setup`: runs install/apf_swarm_nodes/lib/apf_swarm_nodes/apf-swarm.' \
	  'root="$$(cd "$$(dirname "$$(readlink -f "$${BASH_SOURCE[0]}")")/../.." && pwd)"' \
	  'if [ "$${APF_SWARM_ROOT:-}" != "$$root" ]; then' \
	  '  source "$$root/scripts/activate.sh" || exit 1' \
	  'fi' \
	  'exec "$$root/install/apf_swarm_nodes/lib/apf_swarm_nodes/apf-swarm" "$$@"' > '$@'
	@chmod +x '$@'

test: setup
	@$(MAKE) -s warm
	@echo "==> pytest (ROS_DOMAIN_ID=$(ROS_DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)"
	@cd '$(ROOT)' && source scripts/activate.sh && \
	  export ROS_DOMAIN_ID='$(ROS_DOMAIN_ID)' ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST && \
	  python -m pytest -q $(TESTS) $(PYTEST_ARGS)

run: setup
	@echo "==> apf-swarm up --preset triangle --duration 30 --out $(RUN_DIR) (ROS_DOMAIN_ID=$(ROS_DOMAIN_ID))"
	@cd '$(ROOT)' && source scripts/activate.sh && \
	  apf-swarm up --preset triangle --duration 30 --domain-id '$(ROS_DOMAIN_ID)' \
	  --out '$(RUN_DIR)' $(RUN_ARGS)

reproduce: setup
	@echo "==> apf-swarm reproduce --out $(RUN_DIR)-reproduce"
	@cd '$(ROOT)' && source scripts/activate.sh && \
	  apf-swarm reproduce --out '$(RUN_DIR)-reproduce' $(RUN_ARGS)

clean:
	@echo "==> removing build/ install/ log/"
	@cd '$(ROOT)' && rm -rf build install log

distclean: clean
	@echo "==> removing .venv/"
	@rm -rf '$(VENV)'

FORCE:
