# bogiemon: `make demo` and `make test` work on a fresh clone with python3 and make.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp

.PHONY: demo test install bench bench-core bench-drivers bench-simulator study clean

# The venv is (re)built when missing or when pyproject.toml changes.
$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

# The main job on the bundled simulator: a healthy stretch, then a broken spring (about a minute).
demo: $(STAMP)
	$(PY) -m bogiemon.daemon.cli.main demo

# pytest exits 5 when it collects no tests: that is a failure here, never a pass.
test: $(STAMP) system-deps
	$(PY) -m pytest; status=$$?; \
	if [ $$status -eq 5 ]; then echo "make test: pytest collected no tests" >&2; exit 1; fi; \
	exit $$status

bench-core: $(STAMP)
	$(PY) bench/bench_core.py

bench-drivers: $(STAMP)
	$(PY) bench/bench_drivers.py

bench-simulator: $(STAMP)
	$(PY) bench/bench_simulator.py

bench: bench-core bench-drivers

# System packages the tests use: mosquitto (the MQTT tests' broker) and openssl (their test
# certificates), installed with apt-get only when missing and only as root; without them those
# tests are skipped and say why.
.PHONY: system-deps bench-mqtt
system-deps:
	@missing=""; \
	command -v mosquitto >/dev/null 2>&1 || test -x /usr/sbin/mosquitto || missing="$$missing mosquitto"; \
	command -v openssl >/dev/null 2>&1 || missing="$$missing openssl"; \
	if [ -z "$$missing" ]; then exit 0; fi; \
	if [ "$$(id -u)" != 0 ] || ! command -v apt-get >/dev/null 2>&1; then \
		echo "make system-deps: missing$$missing (installing needs root and apt-get): the MQTT tests will be skipped" >&2; exit 0; fi; \
	echo "make system-deps: apt-get install$$missing"; \
	export DEBIAN_FRONTEND=noninteractive; \
	apt-get install -y -qq --no-install-recommends $$missing >/dev/null 2>&1 \
	|| { apt-get update -qq && apt-get install -y -qq --no-install-recommends $$missing; } \
	|| echo "make system-deps: apt-get failed: the MQTT tests will be skipped" >&2

# Alarm delivery against a local mosquitto: the backlog's drain rate, end to end.
bench-mqtt: $(STAMP) system-deps
	$(PY) bench/bench_mqtt.py

# The detection study (docs/study): the paper's Table 4 on the simulator and the defaults' evidence;
# several minutes on two cores. `.venv/bin/bogiemon study --quick -o DIR` runs a small subset.
study: $(STAMP)
	$(VENV)/bin/bogiemon study -o docs/study

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis build *.egg-info
