# Two commands from a fresh clone: `make demo` and `make test`.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint install clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/stt-drake run

lint: $(STAMP)
	$(BIN)/ruff check .

# Drake may use the network only for Meshcat (localhost) and to *register* its package map:
# with "meshcat" alone, constructing any multibody Parser fails offline (checked here), and
# no test may download anything (a `package://drake_models` model would fail to load).
test: $(STAMP)
	$(BIN)/ruff check .
	DRAKE_ALLOW_NETWORK=meshcat:package_map MPLBACKEND=Agg $(BIN)/python -m pytest -n 2 --dist loadfile

clean:
	rm -rf $(VENV) results .pytest_cache .ruff_cache .hypothesis
