# Two commands for a newcomer: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-dev

.PHONY: demo test lint typecheck unit bench clean generate

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

$(VENV)/.installed-run: pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q -e '.[all]'
	touch $@

# --no-compile: pip would compile every file of every package (half of the install's 30 s,
# measured). Python compiles a module when it is first imported and keeps it (`unit` lets it
# write bytecode), so only what is used gets compiled.
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q --no-compile -e '.[dev]'
	touch $@ $(VENV)/.installed-run

demo: $(VENV)/.installed-run
	$(BIN)/opendnc demo

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks tools
	$(BIN)/ruff format --check src tests benchmarks tools

typecheck: $(STAMP)
	$(BIN)/mypy

# Eight workers on two cores: most server and link tests wait on real processes, not the CPU
# (tests/conftest.py starts the longest tests first). Measured on one machine, one day: four
# finish later than six; six took 429 s with the cores idle part of the time; eight took 399 s
# and 395 s with them idle 2 % of it, so more workers can only add contention.
# Bytecode is written even where the environment says not to (PYTHONDONTWRITEBYTECODE is set
# on some machines, CI's included): otherwise every worker, server and command the suite starts
# compiles opendnc's sources again and pytest rewrites every test file again (measured: a
# collection 22 CPU s without its cache, 9 s with it; an import of the server 0.5-1 s dearer).
#
# The suite is collected once before the workers start. On a fresh clone pytest rewrites every
# test file's asserts and Python compiles every source file; eight workers collecting at once each
# would do that again (3.3 CPU s a worker, measured). They now find both cached. A collection error
# is reported by the run that follows.
unit: $(STAMP)
	env -u PYTHONDONTWRITEBYTECODE $(BIN)/pytest -q --collect-only | tail -n 1
	env -u PYTHONDONTWRITEBYTECODE $(BIN)/pytest -q -n 8

# mypy runs beside the suite's start (it takes one core for about 20 s on a fresh clone);
# the target fails if either fails.
test: lint
	$(MAKE) --no-print-directory -j2 typecheck unit

# Regenerate derived sources (the blocking LSV2 client) after editing their originals.
generate: $(STAMP)
	$(BIN)/python tools/unasync.py

bench: $(STAMP)
	$(BIN)/python benchmarks/lsv2_transfer.py
	$(BIN)/python benchmarks/xmodem.py
	$(BIN)/python benchmarks/surface_report.py
	$(BIN)/python benchmarks/cli_startup.py --quick

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
