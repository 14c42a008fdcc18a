# ergoseek: two commands on a fresh machine — `make demo` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.ergoseek-installed

.PHONY: setup system test lint demo bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $@

## setup: the virtual environment with ergoseek and its test tools
setup: $(STAMP)

## system: Debian packages the suite drives for real (PostgreSQL, Chromium, Docker, debootstrap)
system:
	.ci/setup-system

## lint: ruff
lint: setup
	$(BIN)/ruff check .

## test: everything, from a fresh machine
test: setup system lint
	$(BIN)/python -m pytest

## demo: the paper's Exp. 1 reproduced in simulation (figures in out/)
demo: setup
	$(BIN)/ergoseek reproduce exp1 --out out

## bench: every benchmark, one JSON object each
bench: setup
	@for b in benchmarks/*.py; do echo "== $$b"; $(BIN)/python $$b --json; done

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache
