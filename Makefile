# Two entry points do all set-up on a fresh machine: `make demo` and `make test`.
# Everything else here is what they depend on.

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
SYSTEM_PACKAGES := mosquitto mosquitto-clients mbpoll chromium chromium-driver
STAMP_PY := $(VENV)/.stamp-install
STAMP_SYS := $(VENV)/.stamp-system

.PHONY: demo test test-fast check lint typecheck format docs bench clean setup system proto telemetry-demo hil-demo

# The decoders' compiled kernels: compiled on a machine's first run (and after a kernel
# changes), loaded from numba's cache after that.
setup: $(STAMP_PY) $(STAMP_SYS)
	@$(PY) -m grasplink.decoding.warm_up

# Debian packages the test-suite and the integration surfaces use (MQTT broker, Modbus client,
# the headless browser and its driver for the live view's tests, tests/view/). The stamp
# depends on this Makefile, so a package added to the list is installed on a machine that
# was set up before it (the check itself is quick: dpkg -s for each).
$(STAMP_SYS): Makefile | $(VENV)/bin/python
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

# The third-party Sparkplug B host the tests read our output with (tests/telemetry/spb_check.py):
# pysparkplug pins paho-mqtt<2 and we pin 2.x, so it gets a virtual environment of its own.
CHECK_VENV := .venv-check
STAMP_CHECK := $(CHECK_VENV)/.stamp-install
$(STAMP_CHECK): | $(VENV)/bin/python
	$(PYTHON) -m venv $(CHECK_VENV)
	$(CHECK_VENV)/bin/python -m pip install -q pysparkplug==0.6.1 paho-mqtt==1.6.1 protobuf==7.36.2
	@touch $@

HEADLINE := scenes/headline_slip.toml
LOOP_HEADLINE := scenes/loop_headline.toml

demo: setup
	$(VENV)/bin/grasplink demo
	$(VENV)/bin/grasplink run $(LOOP_HEADLINE) --out out/loop_headline
	$(VENV)/bin/grasplink plot out/loop_headline
	$(MAKE) --no-print-directory telemetry-demo
	$(MAKE) --no-print-directory hil-demo

# The gateway live with telemetry on: a private mosquitto on a free 127.0.0.1 port (its
# config under out/telemetry/, stopped at the end), the gateway on a loopback hub publishing
# to it, the loop headline's CAN log replayed onto the hub as the nodes (--nodes-only: the
# gateway masters what it hears), mosquitto_sub recording both topic trees; then the topics,
# a few messages and the slip as telemetry carried it. Needs out/loop_headline (make demo).
# Nothing waits a fixed time: mosquitto and the hub are waited for until they accept a
# connection, the gateway until its --ready-file says it is up (surfaces bound, bus open,
# heartbeat running), each with a timeout and a message naming the log to read.
# Beside the gateway, `grasplink view` (127.0.0.1, a free port) and headless Chromium on it
# (grasplink/surfaces/view/snapshot.py): the replay starts once the page takes frames, and
# the page is saved as out/telemetry/view.png when it shows the slip decoded with its speed.
# No picture is one line and fails the demo at its end (make installed chromium).
VIEW_SNAPSHOT_S := 120
TELEMETRY_OUT := out/telemetry
FREE_PORT := $(PY) -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
# WAIT_PORT NAME PORT LOG: until 127.0.0.1:PORT accepts a connection (20 s at most)
WAIT_PORT := $(PY) -c 'import socket, sys, time; name, port, log = sys.argv[1:]; end = time.monotonic() + 20; up = lambda: socket.socket().connect_ex(("127.0.0.1", int(port))) == 0; [time.sleep(0.05) for _ in iter(lambda: up() or time.monotonic() > end, True)]; up() or sys.exit(f"telemetry-demo: {name} did not accept connections on 127.0.0.1:{port} within 20 s; see {log}")'
GATEWAY_READY_S := 60
telemetry-demo: setup
	@set -e; out=$(TELEMETRY_OUT); rm -rf $$out; mkdir -p $$out; \
	test -f out/loop_headline/can.asc || { echo "telemetry-demo: no out/loop_headline/can.asc; run make demo first"; exit 1; }; \
	mq=$$($(FREE_PORT)); hub=$$($(FREE_PORT)); view=$$($(FREE_PORT)); pids=""; \
	trap 'kill $$pids 2>/dev/null || true; wait 2>/dev/null || true' EXIT; \
	printf 'listener %s 127.0.0.1\nallow_anonymous true\nuser %s\n' $$mq "$$(id -un)" > $$out/mosquitto.conf; \
	mosquitto -c $$out/mosquitto.conf > $$out/mosquitto.log 2>&1 & pids="$$pids $$!"; \
	$(VENV)/bin/grasplink bus hub --port $$hub > $$out/hub.log 2>&1 & pids="$$pids $$!"; \
	$(WAIT_PORT) mosquitto $$mq $$out/mosquitto.log; \
	$(WAIT_PORT) "the CAN hub" $$hub $$out/hub.log; \
	mosquitto_sub -p $$mq -v -t 'grasplink/#' > $$out/json.txt & pids="$$pids $$!"; \
	mosquitto_sub -p $$mq -t 'spBv1.0/#' -F '%t %l bytes' > $$out/sparkplug.txt & pids="$$pids $$!"; \
	$(VENV)/bin/grasplink view --mqtt mqtt://127.0.0.1:$$mq --gateway-id demo \
	  --http 127.0.0.1:$$view > $$out/view.log 2>&1 & pids="$$pids $$!"; \
	$(WAIT_PORT) "grasplink view" $$view $$out/view.log; \
	$(PY) -m grasplink.surfaces.view.snapshot http://127.0.0.1:$$view/ $$out/view.png \
	  --until-slip --timeout $(VIEW_SNAPSHOT_S) --ready-file $$out/view.ready \
	  > $$out/snapshot.log 2>&1 & snap=$$!; pids="$$pids $$snap"; \
	echo "== mosquitto on 127.0.0.1:$$mq, hub on 127.0.0.1:$$hub, the live view on http://127.0.0.1:$$view/; gateway with --mqtt, the loop headline's nodes replayed"; \
	until [ -f $$out/view.ready ] || ! kill -0 $$snap 2>/dev/null; do sleep 0.05; done; \
	printf '[telemetry]\nstate_dir = "%s/state"\n' $$out > $$out/gateway.toml; \
	$(VENV)/bin/grasplink gateway --bus remote:ws://127.0.0.1:$$hub/ --duration 10 \
	  --config $$out/gateway.toml --mqtt mqtt://127.0.0.1:$$mq --mqtt-id demo \
	  --ready-file $$out/gateway.ready & gw=$$!; pids="$$pids $$gw"; \
	waited=0; until [ -f $$out/gateway.ready ]; do \
	  if ! kill -0 $$gw 2>/dev/null; then echo "telemetry-demo: the gateway exited before it was up (its error is above)"; exit 1; fi; \
	  if [ $$waited -ge $$(( $(GATEWAY_READY_S) * 20 )) ]; then echo "telemetry-demo: the gateway was not up within $(GATEWAY_READY_S) s"; exit 1; fi; \
	  sleep 0.05; waited=$$((waited + 1)); done; \
	$(VENV)/bin/grasplink replay out/loop_headline/can.asc --bus remote:ws://127.0.0.1:$$hub/ --nodes-only; \
	wait $$gw; \
	waited=0; until grep -q NDEATH $$out/sparkplug.txt || [ $$waited -ge 100 ]; do sleep 0.05; waited=$$((waited + 1)); done; \
	echo "== JSON topics (messages):"; cut -d' ' -f1 $$out/json.txt | sort | uniq -c; \
	echo "== Sparkplug B topics (messages):"; cut -d' ' -f1 $$out/sparkplug.txt | sort | uniq -c; \
	echo "== the first messages:"; head -n 6 $$out/json.txt | cut -c1-160; \
	echo "== the slip as telemetry carried it (skin values: the first, the first with its speed; belt values):"; \
	grep -m 1 '"slip":true' $$out/json.txt | cut -c1-200 || echo "(no slip decoded)"; \
	grep '"slip":true' $$out/json.txt | grep -m 2 -v '"slip_speed_mm_s":null' | cut -c1-200 || echo "(no slip speed decoded)"; \
	grep -m 2 '"belt":"slip"' $$out/json.txt | cut -c1-200 || true; \
	echo "== the end of the log: nodes lost, alarms retained:"; grep '/alarms ' $$out/json.txt | tail -n 1 | cut -c1-200; \
	echo "all of it: $$out/json.txt, $$out/sparkplug.txt"; \
	if wait $$snap; then echo "== the live view during the slip: $$out/view.png"; \
	else echo "telemetry-demo: no picture of the live view: $$(tail -n 1 $$out/snapshot.log) (see $$out/snapshot.log, $$out/view.log)"; exit 1; fi

# Hardware in the loop (docs/hil.md): the loop headline's nodes and physics in real time on a
# loopback hub, `run --bus --master external`, mastered by a `grasplink gateway` in another
# process, as an integrator's own master would; then what that master did and how the loop
# went, read from the run's can.asc and truth.csv. The pull starts at 2 s (1 s in the scene)
# so a loaded machine's gateway has booted the nodes first, and the gateway's SDO timeout and
# heartbeat allowance are generous, as on any host that is not real-time (docs/hil.md).
# Nothing waits a fixed time: the
# hub is waited for until it accepts a connection, the gateway until its --ready-file; every
# process started here is stopped on the way out, also on failure.
HIL_OUT := out/hil
hil-demo: setup
	@set -e; out=$(HIL_OUT); rm -rf $$out; mkdir -p $$out; \
	hub=$$($(FREE_PORT)); pids=""; \
	trap 'kill $$pids 2>/dev/null || true; wait 2>/dev/null || true' EXIT; \
	sed -e 's/^duration_s = .*/duration_s = 4.5/' -e 's/^start_s = 1.0$$/start_s = 2.0/' \
	  $(LOOP_HEADLINE) > $$out/scene.toml; \
	printf '[gateway]\nsdo_timeout_ms = 5000\nconsumer_allowance_ms = 3000\n[nodes.skin]\nlayout = "alpha0.1"\n[nodes.emg]\ngrip_levels_n = [0.0, 5.0, 8.0, 11.0, 14.0, 20.0]\n[feedback]\nmode = "force_and_slip"\n[reflex]\nthreshold_mm_s = 30.0\n' > $$out/gateway.toml; \
	$(VENV)/bin/grasplink bus hub --port $$hub > $$out/hub.log 2>&1 & pids="$$pids $$!"; \
	$(WAIT_PORT) "the CAN hub" $$hub $$out/hub.log; \
	echo "== HIL: hub on 127.0.0.1:$$hub; a gateway process configured as the scene's controller"; \
	$(VENV)/bin/grasplink gateway --bus remote:ws://127.0.0.1:$$hub/ --config $$out/gateway.toml \
	  --duration 120 --ready-file $$out/gateway.ready > $$out/gateway.log 2>&1 & gw=$$!; pids="$$pids $$gw"; \
	waited=0; until [ -f $$out/gateway.ready ]; do \
	  if ! kill -0 $$gw 2>/dev/null; then echo "hil-demo: the gateway exited before it was up; see $$out/gateway.log"; exit 1; fi; \
	  if [ $$waited -ge $$(( $(GATEWAY_READY_S) * 20 )) ]; then echo "hil-demo: the gateway was not up within $(GATEWAY_READY_S) s"; exit 1; fi; \
	  sleep 0.05; waited=$$((waited + 1)); done; \
	echo "== the scene's nodes and physics on the hub, the gateway process closing the loop"; \
	$(VENV)/bin/grasplink run $$out/scene.toml --bus remote:ws://127.0.0.1:$$hub/ --master external --out $$out/run

# Everything ruff checks and formats.
LINT_PATHS := grasplink tests benchmarks scenes
# pytest-xdist workers: one per core (`make test PYTEST_WORKERS=0` runs serially).
# worksteal: an idle worker takes queued tests from a busy one, so a few long
# tests (scenes, subprocesses) do not leave the other core idle at the end.
PYTEST_WORKERS ?= auto
PYTEST := $(PY) -m pytest -q -n $(PYTEST_WORKERS) --dist worksteal

# The whole suite: static checks first, then every test (wall-clock `slow` ones too).
test: check $(STAMP_CHECK)
	$(PYTEST)

# Quick feedback while editing: the same checks, tests marked `slow` left out
# (threads, sleeps, subprocesses, the hub, --realtime; see tests/conftest.py).
test-fast: check
	$(PYTEST) -m "not slow"

# Static checks, in order: ruff (lint, then format), then mypy.
check: lint typecheck

lint: setup
	$(VENV)/bin/ruff check $(LINT_PATHS)
	$(VENV)/bin/ruff format --check $(LINT_PATHS)

# Types: [tool.mypy] in pyproject.toml (strict for core, devices, the gateway less its
# decoding algorithms, and controllers; the checked-untyped-defs baseline elsewhere).
typecheck: setup
	$(VENV)/bin/mypy grasplink

format: setup
	$(VENV)/bin/ruff format $(LINT_PATHS)

# The Sparkplug B payload classes, generated from the committed schema (grpcio-tools' protoc;
# the protobuf runtime pinned in pyproject.toml matches its generator's version), and their
# typed stub for mypy (mypy-protobuf's plugin).
SPARKPLUG := grasplink/surfaces/telemetry
proto: setup
	cd $(SPARKPLUG) && ../../../$(PY) -m grpc_tools.protoc -I. --python_out=. \
	  --plugin=protoc-gen-mypy=../../../$(VENV)/bin/protoc-gen-mypy --mypy_out=. sparkplug_b.proto

docs: setup
	$(VENV)/bin/grasplink profiles doc --out docs/profiles.md
	$(VENV)/bin/grasplink gateway --print-register-map > docs/modbus.md

bench: setup
	$(PY) benchmarks/bench_network.py
	$(PY) benchmarks/bench_scenes.py
	$(PY) benchmarks/bench_slip_reporting.py
	$(PY) benchmarks/held_out_seeds.py  # the same figures on seeds no rule was tuned on
	$(PY) benchmarks/bench_decoding.py  # shows slip_reporting's trade-off curves
	$(PY) benchmarks/bench_gateway.py
	$(PY) benchmarks/bench_loop.py
	$(PY) benchmarks/bench_telemetry.py
	$(PY) benchmarks/bench_modbus.py
	$(PY) benchmarks/bench_soak.py

clean:
	rm -rf $(VENV) $(CHECK_VENV) .pytest_cache .ruff_cache .mypy_cache
