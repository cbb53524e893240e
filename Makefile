# The two commands: `make demo` runs the stack, `make test` runs the tests. Both build .venv first.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp

.PHONY: install demo test lint typecheck unit bench schemas tools clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

# System tools the tests use: a real compose implementation to validate compose.yaml (no engine needed), and
# Debian's chromium to render the report headless.
tools:
	@command -v docker-compose >/dev/null 2>&1 || { \
	  echo "installing docker-compose (Debian) to validate compose.yaml"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq docker-compose >/dev/null) \
	  || echo "warning: could not install docker-compose; the compose validation test will fail"; }
	@command -v chromium >/dev/null 2>&1 || { \
	  echo "installing chromium (Debian) to render the report in the tests"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
	  || echo "warning: could not install chromium; the report rendering tests will fail"; }

# The demo: the compose stack as local processes; the recording gets Foxglove scene channels, and the run
# ends with its report (fixstream report) and prints where the report is.
demo: install
	FIXSTREAM_RECORDER_FOXGLOVE=$${FIXSTREAM_RECORDER_FOXGLOVE:-true} $(VENV)/bin/fixstream up --report

lint: install
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

typecheck: install
	$(PY) -m mypy schemas shared services

unit: install tools
	$(PY) -m pytest -q

test: lint typecheck unit

bench: install
	$(PY) -m bench

schemas: install
	$(PY) -m schemas.export

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
