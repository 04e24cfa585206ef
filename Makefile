# The two commands of README.md: `make demo` and `make test`. Each does the set-up it needs.
SHELL := /bin/bash
VENV ?= .venv
PYTHON := $(VENV)/bin/python
ROS_DOMAIN_ID ?= 42
# pytest-xdist processes of `make test`, each with its own DDS domain (test/xdist_workers.py).
TEST_WORKERS ?= 2

# DDS stays on this host: see README.md, "DDS on this host".
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export ROS_DOMAIN_ID
export FASTDDS_DEFAULT_PROFILES_FILE ?= $(CURDIR)/config/fastdds_profile.xml
export AMENT_PREFIX_PATH := $(abspath $(VENV))$(if $(AMENT_PREFIX_PATH),:$(AMENT_PREFIX_PATH))

.PHONY: setup test demo lint bench clean default-data

# $(call run_subcommand,NAME): run `face-tracking NAME --out out` if that subcommand is registered
# (face_tracking_ros/cli/main.py, SUBCOMMANDS), else say so and fail: never a stand-in.
define run_subcommand
	@if $(PYTHON) -c 'import sys; from face_tracking_ros.cli.main import SUBCOMMANDS; \
		sys.exit("$(1)" not in SUBCOMMANDS)'; then \
		$(PYTHON) -m face_tracking_ros.cli.main $(1) --out out; \
	else \
		echo 'make $(1): no "$(1)" subcommand yet (face_tracking_ros/cli/$(1).py); nothing to run'; \
		exit 1; \
	fi
endef

setup:
	VENV=$(abspath $(VENV)) bash tools/setup_env.sh

test: setup
	$(PYTHON) -m pytest -n $(TEST_WORKERS) --dist loadfile

demo: setup
	$(call run_subcommand,demo)

lint: setup
	$(VENV)/bin/ruff check face_tracking_ros test tools setup.py
	$(VENV)/bin/ruff format --check face_tracking_ros test tools setup.py

bench: setup
	$(call run_subcommand,bench)

# The packaged default face models and expression classifier (committed; see the script).
default-data: setup
	PYTHON=$(abspath $(PYTHON)) bash tools/make_default_data.sh

clean:
	rm -rf $(VENV) build out .pytest_cache .ruff_cache
