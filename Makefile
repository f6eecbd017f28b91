# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench clean clean-kernels install docs browser-test

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# The install ends by compiling the kernels of the first commands a user runs
# (cellplan/warmup.py), so a first `cellplan solve` loads them from numba's cache.
$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install -q -e '.[dev]'
	$(BIN)/python -m cellplan.warmup
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/cellplan demo -o cellplan-out

# The suite runs on every core (pytest-xdist): on 2 idle cores about 8 min (8 min 1 s, 2026-11-28).
TEST_WORKERS ?= auto
test: $(STAMP)
	$(BIN)/python -m pytest -n $(TEST_WORKERS)

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy

# The API reference, from the docstrings (numpydoc), into build/api; a warning fails it.
docs: $(STAMP)
	$(BIN)/python docs/build_api.py build/api

# The demo report and the 3-D viewer page in a real headless browser (Chromium from Debian's
# packages).
browser-test: $(STAMP)
	command -v chromium-headless-shell >/dev/null || \
		(apt-get update -qq && apt-get install -y -qq chromium-headless-shell)
	$(BIN)/python -m pip install -q -e '.[dev,browser]'
	CELLPLAN_SCREENSHOT=build/report-screenshot.png CELLPLAN_SCREENSHOT_3D=build/viewer-screenshot.png \
		$(BIN)/python -m pytest -m slow -s tests/test_report_browser.py tests/test_view3d_browser.py

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

# numba's on-disk cache checks the mtime of a kernel's own file only: after editing a
# module that kernels call (stencils.py, noisy.py, ...), drop the compiled kernels.
clean-kernels:
	find src -name '*.nbi' -delete -o -name '*.nbc' -delete

clean:
	rm -rf $(VENV) cellplan-out .pytest_cache .hypothesis build
	find src -name '*.nbi' -delete -o -name '*.nbc' -delete
