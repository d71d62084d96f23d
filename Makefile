# Two entry points do all set-up on a fresh machine: `make demo` and `make test`.
# Everything else here is what they depend on.

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
SYSTEM_PACKAGES := mosquitto mbpoll
STAMP_PY := $(VENV)/.stamp-install
STAMP_SYS := $(VENV)/.stamp-system

.PHONY: demo test lint format docs bench clean setup system

setup: $(STAMP_PY) $(STAMP_SYS)

# Debian packages the test-suite and the integration surfaces use (MQTT broker, Modbus client).
$(STAMP_SYS): | $(VENV)/bin/python
	@missing=""; for p in $(SYSTEM_PACKAGES); do \
	  dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO="sudo"; \
	  $$SUDO apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	fi
	@# mosquitto's package starts a system broker on :1883; tests start their own on high ports.
	@touch $@

$(VENV)/bin/python:
	$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "grasplink needs Python >= 3.11"'
	$(PYTHON) -m venv $(VENV)

$(STAMP_PY): pyproject.toml | $(VENV)/bin/python
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	@touch $@

HEADLINE := scenes/headline_slip.toml

demo: setup
	$(VENV)/bin/grasplink demo
	$(VENV)/bin/grasplink run $(HEADLINE) --out out/headline
	$(VENV)/bin/grasplink plot out/headline

test: setup
	$(VENV)/bin/ruff check grasplink tests benchmarks
	$(PY) -m pytest -q

lint: setup
	$(VENV)/bin/ruff check grasplink tests benchmarks

format: setup
	$(VENV)/bin/ruff format grasplink tests benchmarks

docs: setup
	$(VENV)/bin/grasplink profiles doc --out docs/profiles.md

bench: setup
	$(PY) benchmarks/bench_network.py
	$(PY) benchmarks/bench_scenes.py

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
