# ebr-mitsuba: every target bootstraps .venv and the LLVM runtime idempotently.
SHELL := /bin/bash
VENV  := .venv
PY    := $(VENV)/bin/python
STAMP := $(VENV)/.ebr-installed
PYTEST_ARGS ?=
EBR_DATA_DIR ?= ../shared/data

.PHONY: demo test test-all bench docs lint bootstrap llvm clean

bootstrap: $(STAMP)

# Dr.Jit's LLVM backend needs LLVM >= 17 (the system's LLVM 15 fails with "Cannot select ... fminimum").
llvm:
	@if compgen -G '/usr/lib/*/libLLVM.so.19*' >/dev/null || compgen -G '/usr/lib/*/libLLVM-1[7-9]*.so*' >/dev/null \
	   || compgen -G '/usr/lib/*/libLLVM.so.1[7-9]*' >/dev/null || compgen -G '/usr/lib/*/libLLVM.so.2*' >/dev/null \
	   || [ -n "$$DRJIT_LIBLLVM_PATH" ]; then \
	  true; \
	elif command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	  echo "[bootstrap] installing libllvm19 (Dr.Jit's LLVM backend needs LLVM >= 17)" >&2; \
	  (apt-get install -y -qq libllvm19 >/dev/null 2>&1 || (apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq libllvm19 >/dev/null)) \
	  || { echo "error: could not install libllvm19; run 'apt-get install -y libllvm19' as root (Dr.Jit needs LLVM >= 17)" >&2; exit 2; }; \
	else \
	  echo "error: LLVM >= 17 runtime not found; run 'sudo apt-get install -y libllvm19' or set DRJIT_LIBLLVM_PATH (the system's LLVM 15 crashes Dr.Jit)" >&2; exit 2; \
	fi

$(STAMP): pyproject.toml | llvm
	@test -x $(PY) || python3 -m venv $(VENV)
	@echo "[bootstrap] installing ebr-mitsuba into $(VENV)" >&2
	@$(PY) -m pip install -q --disable-pip-version-check torch==2.13.0
	@$(PY) -m pip install -q --disable-pip-version-check -e '.[dev]'
	@touch $(STAMP)

demo: llvm $(STAMP)
	$(VENV)/bin/ebr demo

test: llvm $(STAMP)
	$(PY) -m pytest -q $(PYTEST_ARGS)

test-all: llvm $(STAMP)
	$(PY) -m pytest -q -m "" $(PYTEST_ARGS)

bench: llvm $(STAMP)
	$(VENV)/bin/ebr bench all

# Regenerates every generated page: command and plugin references, the validation table, the benchmarks.
docs: llvm $(STAMP)
	$(PY) -m ebr_mitsuba.docgen --out docs
	$(VENV)/bin/ebr validate --markdown docs/validation_table.md
	rm -rf /tmp/ebr-demo-docs && $(VENV)/bin/ebr demo --out /tmp/ebr-demo-docs --docs docs
	$(VENV)/bin/ebr gallery $(EBR_DATA_DIR)/photos/flash_only --docs docs
	$(VENV)/bin/ebr bench all

lint: $(STAMP)
	$(VENV)/bin/ruff check ebr_mitsuba plugins tests
	$(VENV)/bin/ruff format --check ebr_mitsuba plugins tests

clean:
	rm -rf $(VENV) build *.egg-info
