# The two commands of the README. Both create .venv if missing and install into it.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Demo knobs (see README): DEPTH=gt|learned, OUT=where the demo writes.
DEPTH ?= gt
OUT ?= cache/demo

.PHONY: demo test test-all bench install clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# torch is installed first and pinned, so that the project's own install never pulls a CUDA build.
$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

# `make test`: everything but the tests marked slow (a few minutes on 2 cores); `make test-all`: all of it,
# the fault-injection suite (tests/faults, marker faults) included.
test: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow"

test-all: $(STAMP)
	$(BIN)/python -m pytest -q

# OMP_WAIT_POLICY=PASSIVE: torch's idle threads sleep instead of spinning, so a busy 2-core machine
# does not slow training 10-30x (measured; see BENCHMARKS.md).
demo: $(STAMP)
	OMP_WAIT_POLICY=PASSIVE $(BIN)/python -m scripts.demo --out $(OUT) --depth $(DEPTH)

bench: $(STAMP)
	$(BIN)/python -m benchmarks.run_all

clean:
	rm -rf $(VENV) cache/demo
