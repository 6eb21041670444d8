# citylod — `make demo` and `make test` work on a fresh Debian machine with Python 3.11 and no display.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test bench lint sysdeps venv kernels validator clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	@touch $(STAMP)

venv: $(STAMP)

# The DSM build's kernels compiled ahead of time (citylod.lod.kernels.aot): a no-op when they are up to date, a
# minute when a kernel changed; builds run on the JIT kernels when this cannot compile them. Then numba's cache
# is filled for points builds (20 s once, a second after).
kernels: $(STAMP)
	@$(VENV)/bin/citylod build-kernels

sysdeps:
	@./scripts/sysdeps.sh

demo: $(STAMP) sysdeps kernels
	$(VENV)/bin/citylod demo demo_out

# CesiumGS's 3d-tiles-validator for tests/io/test_validator.py (node + npm); prints why and goes on without it.
validator:
	@./scripts/validator.sh

test: $(STAMP) sysdeps kernels validator
	xvfb-run -a -s "-screen 0 1600x1200x24" $(PY) -m pytest -n 2 --dist loadfile -q

bench: $(STAMP) sysdeps kernels
	$(VENV)/bin/citylod bench-suite bench_out

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests
	$(VENV)/bin/lint-imports
	$(VENV)/bin/mypy

clean:
	rm -rf $(VENV) demo_out bench_out .validator .validator.skipped
