# The two commands: `make demo` runs the stack, `make test` runs the tests. Both build .venv first.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp

LOCK   := requirements.lock
UV     := $(VENV)-tools/bin/uv

.PHONY: install demo test lint typecheck unit bench schemas tools clean lock

# The install is the lock file's exact versions, every file checked against its hash, then the project itself
# (editable, no dependency resolution, built with the locked setuptools). `make lock` refreshes the lock.
$(STAMP): pyproject.toml $(LOCK)
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --require-hashes --no-deps -r $(LOCK)
	$(PY) -m pip install -q --no-deps --no-build-isolation -e .
	$(PY) -m pip check
	touch $(STAMP)

install: $(STAMP)

# Re-resolve every dependency (pyproject.toml's, dev extras and the build backend) to the newest versions that
# fit, for every Python from 3.11 on, with the hashes of every file of each version. uv lives in its own venv
# so that it is not part of the locked program.
lock:
	test -x $(UV) || { $(PYTHON) -m venv $(VENV)-tools && $(VENV)-tools/bin/pip install -q uv==0.13.9; }
	printf 'setuptools>=77\nwheel\n' | $(UV) pip compile pyproject.toml - --extra dev --extra parquet --generate-hashes \
	  --universal --fork-strategy fewest --python-version 3.11 --no-header -q -o $(LOCK)
	@echo "wrote $(LOCK); run make install (or make test) to use it"

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
	rm -rf $(VENV) $(VENV)-tools build *.egg-info .pytest_cache .mypy_cache .ruff_cache
