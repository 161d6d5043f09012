# Two commands from a fresh clone: `make demo` and `make test`.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-fast bench-history bench-compare lint install lock clean system-packages docs

# pyproject.toml gives compatible ranges; requirements.lock pins the exact versions installed
# here and in CI (.ci/run calls `make test`), so both stay reproducible.
$(STAMP): pyproject.toml requirements.lock
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade -c requirements.lock pip
	$(BIN)/python -m pip install --quiet -c requirements.lock -e '.[test]'
	# the crowd extra without JuPedSim's visualizer (PySide6, vtk: ~1.2 GB it never imports)
	$(BIN)/python -m pip install --quiet --no-deps -c requirements.lock jupedsim shapely Deprecated wrapt
	touch $(STAMP)

install: $(STAMP)

# Regenerate requirements.lock from the venv (after changing a range in pyproject.toml and
# `pip install --upgrade -e '.[test]'` into it); review the diff before committing it.
lock: $(STAMP)
	{ echo "# Exact versions CI installs (\`make install\`: pip install -c requirements.lock -e '.[test]')."; \
	  echo "# Generated with \`make lock\` (pip freeze --all --exclude-editable of the venv, Python 3.11, Linux"; \
	  echo "# x86_64); pyproject.toml holds the compatible ranges. Do not edit by hand."; \
	  $(BIN)/python -m pip freeze --all --exclude-editable; } > requirements.lock.tmp
	mv requirements.lock.tmp requirements.lock

demo: $(STAMP)
	$(BIN)/stt-drake run

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports

# Drake may use the network only for Meshcat (localhost), to *register* its package map and
# for LCM (UDP multicast, which the two-process robot test needs on the loopback): with
# "meshcat" alone, constructing any multibody Parser fails offline (checked here), and no
# test may download anything (a `package://drake_models` model would fail to load).
PYTEST := DRAKE_ALLOW_NETWORK=meshcat:package_map:lcm MPLBACKEND=Agg $(BIN)/python -m pytest -n 2 --dist loadfile

# Every test; the 25 slowest are listed at the end (CI keeps them in its log).
test: $(STAMP) system-packages
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	$(PYTEST) --durations=25

# A maintainer's minute: everything but the slow, notebook and browser tests (< 90 s on 2 cores).
test-fast: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	$(PYTEST) -m "not slow and not notebook and not browser" --durations=10

# The benchmark history (pytest-benchmark; benchmarks/): every run is saved in .benchmarks/
# and compared with the previous saved run (rows listed, nothing fails).
bench-history: $(STAMP)
	$(BIN)/python -m pytest benchmarks -p no:xdist --benchmark-autosave --benchmark-compare \
	  --benchmark-columns=min,median,rounds

# The working tree against main on this machine (quiet): names every row whose median is more
# than 10 % slower (exit 1).
bench-compare: $(STAMP)
	$(BIN)/python benchmarks/compare_with_main.py main

# The documentation site (Sphinx; pages in docs/, the API from the docstrings) into
# docs/_build/html; warnings are errors, as in tests/docs/test_docs_site.py.
docs: $(STAMP)
	$(BIN)/python -m sphinx -W --keep-going -b html docs docs/_build/html

# Graphviz (`stt-drake diagram`) and headless Chromium (the replay test) are Debian packages.
# As root they are installed directly; otherwise through sudo (which may ask for a
# password); with neither, or when the install fails, the recipe stops (exit 1) with the
# command to run. Nothing is skipped: the diagram and replay tests need both.
APT_INSTALL := apt-get install -y graphviz chromium
system-packages:
	@if command -v dot >/dev/null 2>&1 && command -v chromium >/dev/null 2>&1; then exit 0; fi; \
	stop() { echo "$$1; install them with:" >&2; echo "  sudo $(APT_INSTALL)" >&2; exit 1; }; \
	if [ "$$(id -u)" = 0 ]; then as=""; \
	elif command -v sudo >/dev/null 2>&1; then as="sudo"; \
	else stop "the tests need the Debian packages graphviz and chromium, and installing them needs root or sudo"; fi; \
	echo "installing the Debian packages graphviz and chromium for the diagram and replay tests$${as:+ (through sudo)}"; \
	{ $$as env DEBIAN_FRONTEND=noninteractive apt-get update -qq && \
	  $$as env DEBIAN_FRONTEND=noninteractive $(APT_INSTALL) -qq >/dev/null; } || \
	  stop "installing graphviz and chromium failed"

clean:
	rm -rf $(VENV) results .pytest_cache .ruff_cache .hypothesis .benchmarks
