# The two commands: `make demo` runs the stack, `make test` runs the tests. Both build .venv first.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp

LOCK   := requirements.lock
UV     := $(VENV)-tools/bin/uv

.PHONY: install demo test lint typecheck unit bench schemas tools images demo-containers clean lock

# The install is the lock file's exact versions, every file checked against its hash, then the project itself
# (editable, no dependency resolution, built with the locked setuptools). `make lock` refreshes the lock.
$(STAMP): pyproject.toml $(LOCK)
	rm -rf $(VENV) *.egg-info
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

# System tools the tests use, Debian packages installed only when missing (one apt-get for all): docker-compose
# validates compose.yaml and drives the container test; chromium renders the report headless; podman runs the
# containers, catatonit is its init (compose's `init: true`), debootstrap builds the base image (make images).
# podman also gets `default_ulimits = []` (a containers.conf drop-in): its default open-files limit is above this
# machine's hard limit, and runc then refuses to start any container.
TOOLS           := docker-compose chromium podman catatonit debootstrap
CONTAINERS_CONF := /etc/containers/containers.conf.d/fixstream.conf

tools:
	@missing=""; for tool in $(TOOLS); do \
	  PATH="$$PATH:/usr/sbin" command -v $$tool >/dev/null 2>&1 || missing="$$missing $$tool"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing (Debian):$$missing"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null) \
	  || echo "warning: could not install$$missing; the tests that need them will fail or skip"; fi
	@if command -v podman >/dev/null 2>&1 && [ ! -f $(CONTAINERS_CONF) ]; then \
	  (mkdir -p $(dir $(CONTAINERS_CONF)) && printf '%s\n' '# written by fixstream make tools (docs/stack.md)' \
	    '[containers]' 'default_ulimits = []' > $(CONTAINERS_CONF) && echo "wrote $(CONTAINERS_CONF)") \
	  || echo "warning: could not write $(CONTAINERS_CONF); podman may refuse to start containers"; fi

# The images where none can be pulled (docs/stack.md): a Debian base from debootstrap, then the Dockerfile on it,
# tagged fixstream:latest. Cached by what goes into them; a warm call costs seconds.
images: install tools
	$(PY) tests/container_support.py images

# The demo as real containers under podman (no registry): the images, podman's Docker API socket, the
# healthcheck driver and a writable ./recordings, all set up for you (docs/stack.md, "Containers with podman").
demo-containers: images
	$(PY) tests/container_support.py demo

# The demo: the compose stack as local processes; the recording gets Foxglove scene channels, and the run
# ends with its report (fixstream report) and prints where the report is.
demo: install
	FIXSTREAM_RECORDER_FOXGLOVE=$${FIXSTREAM_RECORDER_FOXGLOVE:-true} $(VENV)/bin/fixstream up --report

lint: install
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .
	$(VENV)/bin/lint-imports --no-cache

typecheck: install
	$(PY) -m mypy schemas shared services tools

unit: install tools
	$(PY) -m pytest -q

test: lint typecheck unit

bench: install
	$(PY) -m bench

schemas: install
	$(PY) -m schemas.export

clean:
	rm -rf $(VENV) $(VENV)-tools build *.egg-info .pytest_cache .mypy_cache .ruff_cache
