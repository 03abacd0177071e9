# bogiemon: `make demo` and `make test` work on a fresh clone with python3 and make.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp

.PHONY: demo fleet-demo test lint install bench bench-core bench-drivers bench-simulator bench-daemon bench-study bench-profile soak fuzz study evaluate demo-calibration clean

# The venv is (re)built when missing or when pyproject.toml changes.
$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

# The main job on the bundled simulator: a healthy stretch, then a broken spring (about a minute).
demo: $(STAMP)
	$(PY) -m bogiemon demo

# The back office on a simulated fleet (docs/fleet.md): 8 wagons x 3 days, a broken spring on two
# of them and a noisy sensor on a third; simulate, analyze on a local Dask cluster, commission each
# wagon from its first day, judge, and write the one-page report (a few minutes).
FLEET_DEMO := build/fleet-demo
fleet-demo: $(STAMP)
	rm -rf $(FLEET_DEMO) && mkdir -p $(FLEET_DEMO)
	$(VENV)/bin/bogiemon fleet simulate $(FLEET_DEMO)/fleet --wagons 8 --days 3 --commission-runs 6 --runs-per-day 2
	$(VENV)/bin/bogiemon fleet analyze $(FLEET_DEMO)/fleet -o $(FLEET_DEMO)/windows
	$(VENV)/bin/bogiemon fleet calibrate --uncommissioned --fleet $(FLEET_DEMO)/fleet --windows $(FLEET_DEMO)/windows
	$(VENV)/bin/bogiemon fleet judge $(FLEET_DEMO)/windows -o $(FLEET_DEMO)/judged
	$(VENV)/bin/bogiemon fleet report $(FLEET_DEMO)/judged -o $(FLEET_DEMO)/report
	@echo "make fleet-demo: the work list is $(abspath $(FLEET_DEMO))/report/index.html"

# The static checks, run first by `make test`: ruff ([tool.ruff] in pyproject.toml: pyflakes,
# pycodestyle, bugbear, pyupgrade) and mypy ([tool.mypy]: bogiemon/, tests/ and bench/; strict over
# detection/, drivers/, judgement/ and daemon/). Cold (empty .mypy_cache) about 30 CPU s, then 2 to 3 s.
lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m mypy

# First the static checks (lint above), then the house's import contract (tests/house.py: the
# layers in pyproject.toml), then pytest.
# pytest exits 5 when it collects no tests: that is a failure here, never a pass.
# The tests run in TEST_WORKERS pytest-xdist processes, twice the cores and at most 8 by default:
# many of them wait on processes, sockets and the clock rather than compute (tests/conftest.py says
# how the work is grouped and ordered). `make test TEST_WORKERS=0` runs them in one process.
# The tests cache their bytecode (__pycache__, ignored by git) even where PYTHONDONTWRITEBYTECODE is
# set: every worker, Dask worker and command the tests start imports the same modules, and pytest
# rewrites every test module in every worker; uncached, collecting took a worker 6-7.5 s of CPU
# instead of 3.3 s (2 cores, 2026-12-03).
TEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); echo $$((2 * n < 8 ? 2 * n : 8)))
test: export PYTHONDONTWRITEBYTECODE =
test: $(STAMP) lint system-deps
	$(PY) tests/house.py
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadgroup --no-loadscope-reorder; status=$$?; \
	if [ $$status -eq 5 ]; then echo "make test: pytest collected no tests" >&2; exit 1; fi; \
	exit $$status

# The slow tier (tests/tier.py): the tests marked slow_tier at their full size (long property runs
# whose fast example `make test` runs); `make test-all` is both.
.PHONY: test-slow test-all
test-slow: export PYTHONDONTWRITEBYTECODE =
test-slow: export BOGIEMON_TEST_TIER = slow
test-slow: $(STAMP)
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadgroup --no-loadscope-reorder -m slow_tier

test-all: test test-slow

# Benchmarks print figures (median, min and max of several runs; ratios against a baseline
# measured in the same run); timing is never asserted in a test. `make bench` runs every part and
# prints one table, writing bench/results/latest.json (about 50 minutes: the daemon runs at real
# time, the study once); the parts run alone below. The bench extra brings py-spy for the profile.
# The daemon's figures, and the CPU of `analyze` (an hour, CSV and Parquet) and of `fleet analyze`
# (per wagon-hour, 1 worker), are guarded against the last ones recorded on this machine class
# (bench/guard.py, bench/results/records.json): MISSED and exit 1 past +25 %. Recording is a step
# of its own: `make bench BENCH_ARGS=--record` (or bench-daemon, bench-core, bench-fleet).
BENCH_ARGS ?=
BENCH_STAMP := $(VENV)/.bench-stamp
$(BENCH_STAMP): $(STAMP)
	$(PY) -m pip install --quiet --disable-pip-version-check -e '.[test,bench]'
	touch $(BENCH_STAMP)

bench: $(BENCH_STAMP)
	$(PY) bench/suite.py $(BENCH_ARGS)

bench-core: $(STAMP)
	$(PY) bench/bench_core.py $(BENCH_ARGS)

bench-drivers: $(STAMP)
	$(PY) bench/bench_drivers.py

bench-simulator: $(STAMP)
	$(PY) bench/bench_simulator.py

bench-daemon: $(STAMP)
	$(PY) bench/bench_daemon.py $(BENCH_ARGS)

bench-study: $(STAMP)
	$(PY) bench/bench_study.py

# The import of the fleet's page (`import bogiemon.fleet.report`) in fresh interpreters, beside its
# 0.3 s target; BENCH_ARGS=--why adds its heaviest modules (python -X importtime).
.PHONY: bench-import
bench-import: $(STAMP)
	$(PY) bench/bench_import.py $(BENCH_ARGS)

# The gateway (docs/gateway.md): the bundle's install on disk (build it first: make bundle), a
# wagon's day of CPU with and without a duty cycle from stretches measured at real time (about 12
# minutes), what a duty cycle costs the detection of a broken spring (a 2 h simulated run, once),
# and the peak RSS of `bogiemon run` on hub CAN as the bundle installs it (about 4 minutes).
.PHONY: bench-gateway bench-vcan
bench-gateway: $(STAMP)
	$(PY) bench/bench_gateway.py $(BENCH_ARGS)

# The CAN path on a real kernel (root; the VM of make test-vcan): `bogiemon run` on vcan0 beside
# candump on the same frames, their CPU ratio and the daemon's peak RSS (about 7 minutes).
bench-vcan: $(STAMP) vm-setup
	$(PY) bench/bench_vcan.py $(BENCH_ARGS)

# The back office: `fleet analyze` of a simulated fleet on 1 and 2 Dask workers, against `analyze`.
.PHONY: bench-fleet
bench-fleet: $(STAMP)
	$(PY) bench/bench_fleet.py $(BENCH_ARGS)

# The daemon's hot path on the CAN feed at 500 Hz under py-spy, before and after the CAN reader
# coalesces its wake-ups (about 20 minutes).
bench-profile: $(BENCH_STAMP)
	$(PY) bench/profile_daemon.py

# The soak test (not part of `make test`): 24 simulated hours through the daemon with faults,
# gaps, sensor faults, reloads and restarts; checks memory, events and counters (a few minutes).
soak: $(STAMP)
	$(PY) bench/soak.py

# kill -9 at random moments of `bogiemon replay` and `bogiemon run` (bench/kill9.py): 120 trials,
# seeded; per command the store-open failures, lost and duplicated events and state mismatches;
# then 20 of `run` with its recorder on a small tmpfs (root only), the disk filled to its last page
# with what it left, and a start that must give it back and commit (a few minutes; a handful of the
# same trials run in `make test`, tests/daemon/test_kill9.py and test_kill9_disk.py).
.PHONY: kill9
kill9: $(STAMP)
	$(PY) bench/kill9.py

# System packages the tests use: mosquitto (the MQTT tests' broker), openssl (their test
# certificates) and chromium (the headless browser that opens the fleet report's page), installed
# with apt-get only when missing and only as root; without them those tests are skipped and say why.
.PHONY: system-deps bench-mqtt
system-deps:
	@missing=""; \
	command -v mosquitto >/dev/null 2>&1 || test -x /usr/sbin/mosquitto || missing="$$missing mosquitto"; \
	command -v openssl >/dev/null 2>&1 || missing="$$missing openssl"; \
	command -v chromium >/dev/null 2>&1 || missing="$$missing chromium"; \
	if [ -z "$$missing" ]; then exit 0; fi; \
	if [ "$$(id -u)" != 0 ] || ! command -v apt-get >/dev/null 2>&1; then \
		echo "make system-deps: missing$$missing (installing needs root and apt-get): the tests that use them will be skipped" >&2; exit 0; fi; \
	echo "make system-deps: apt-get install$$missing"; \
	export DEBIAN_FRONTEND=noninteractive; \
	apt-get install -y -qq --no-install-recommends $$missing >/dev/null 2>&1 \
	|| { apt-get update -qq && apt-get install -y -qq --no-install-recommends $$missing; } \
	|| echo "make system-deps: apt-get failed: the tests that use$$missing will be skipped" >&2

# Alarm delivery against a local mosquitto: the backlog's drain rate, end to end.
bench-mqtt: $(STAMP) system-deps
	$(PY) bench/bench_mqtt.py

# The fuzz suite (bench/fuzz.py; not part of `make test`, whose tests/test_fuzz_quick.py runs its
# --quick form): every decoder and parser fed seeded generated and mutated inputs (120 to 100 000 per
# target: compressed and Parquet recordings, the recorder on a full tmpfs, reload storms, floods of
# signals at a running daemon too), each under a limit of CPU time; prints per target the inputs, clear errors, crashes, hangs and silently wrong
# results, saves each distinct finding under bench/fuzz_crashes/ and exits 1 on a crash or a hang
# (about 35 minutes on two cores; the recorder's target mounts its tmpfs as root, else is not run).
fuzz: $(STAMP)
	$(PY) bench/fuzz.py

# The detection study (docs/study): the paper's Table 4 on the simulator and the defaults' evidence;
# several minutes on two cores. `.venv/bin/bogiemon study --quick -o DIR` runs a small subset.
study: $(STAMP)
	$(VENV)/bin/bogiemon study -o docs/study

# The robustness evaluation (docs/robust): a varied simulated fleet, the shipped models fitted on
# its training wagons, every detection method judged on the others (about 40 minutes on two
# cores). DATA keeps the simulated windows for another run: make evaluate DATA=build/robust.pkl
evaluate: $(STAMP)
	$(VENV)/bin/bogiemon evaluate --fit-models -o docs/robust $(if $(DATA),--data $(DATA))

# The transfer evaluation (docs/robust/transfer): the priors fitted on the training fleet of each
# wagon model (A, and B built independently) judged on both models' evaluation fleets against
# issue 26's targets, each wagon commissioned on a random draw of 10 runs per load; 30 h of
# healthy running per model (TRANSFER_PLAN=--full: 100 h, about 90 minutes on two cores). DATA
# keeps the simulated windows (make transfer DATA=build/transfer.pkl): judging them again takes
# about 10 minutes on a quiet machine.
TRANSFER_PLAN ?=
.PHONY: transfer
transfer: $(STAMP)
	$(VENV)/bin/bogiemon evaluate --transfer $(TRANSFER_PLAN) -o docs/robust/transfer $(if $(DATA),--data $(DATA))

# The configuration reference (docs/configuration.md): every section and field, generated from the
# config models' descriptions (a test fails while the committed page differs from them).
.PHONY: config-reference
config-reference: $(STAMP)
	$(VENV)/bin/bogiemon check-config --reference > docs/configuration.md.tmp && mv docs/configuration.md.tmp docs/configuration.md

# The demo wagon's commissioning (config/demo_calibration.toml), as a keeper does it: two hours
# of the healthy wagon at the demo's load on varied tracks and speeds, then `bogiemon calibrate`.
DEMO_RUNS := build/demo-commissioning
demo-calibration: $(STAMP)
	rm -rf $(DEMO_RUNS) && mkdir -p $(DEMO_RUNS)
	for i in 0 1 2 3 4 5 6 7 8 9 10 11; do \
		case $$((i % 3)) in 0) track=erri-low;; 1) track=erri-high;; *) track=fra-5;; esac; \
		if [ $$((i % 2)) = 0 ]; then speed=0:60,600:100; else speed=0:100,600:60; fi; \
		$(VENV)/bin/bogiemon simulate --load full --track $$track --speed-profile $$speed --duration-s 600 \
			--seed $$((100 + i)) -o $(DEMO_RUNS)/healthy-$$i.csv || exit 1; \
	done
	$(VENV)/bin/bogiemon calibrate $(DEMO_RUNS)/healthy-*.csv --load full -o config/demo_calibration.toml

# The gateway's offline bundle (docs/gateway.md, bundle/build.py): bogiemon's wheel and every
# wheel of bundle/lock/<ARCH>-cp3XX.txt for CPython 3.11-3.13, the units, the default config and
# install.sh, as build/bundle/bogiemon-<version>-<ARCH>.tar.gz (about 60 MB; a minute, the wheels
# from PyPI through pip's cache). `make lock` resolves the lock files again from pyproject.toml's
# dependencies (a few minutes); the bundle refuses a lock that no longer matches them. Both run in
# a small venv of their own (build/tools: pip only), not the development venv.
ARCH ?= $(shell uname -m)
TOOLS := build/tools/bin/python
$(TOOLS):
	$(PYTHON) -m venv build/tools

.PHONY: bundle lock
bundle: $(TOOLS)
	$(TOOLS) bundle/build.py --arch $(ARCH)

lock: $(TOOLS)
	$(TOOLS) bundle/lock.py

# The bundle tested for real (not part of `make test`): built for ARCH, installed in a Debian root
# of that architecture made by debootstrap from Debian's packages (arm64 under qemu-user-static;
# cached in build/debian-<suite>-<arch>, DEBIAN_SUITE=bookworm by default), with no network, where
# check-config, a replay of a simulated broken spring and `bogiemon run` on it must confirm the
# fault and store it; then an upgrade and a rollback (tests/bundle/). Root only. test-arm is
# ARCH=aarch64: the first run about 15 minutes (the root), later ones about 6 (docs/gateway.md).
FAULT_RUN := build/bundle/broken-spring.csv
$(FAULT_RUN): | $(STAMP)
	mkdir -p build/bundle
	$(VENV)/bin/bogiemon simulate --load full --track erri-low --speed-kmh 80 --duration-s 240 \
		--fault type_a:rear_outer:0.0@leading-left --fault-at-s 60 --seed 2 -q -o $@

.PHONY: test-arm test-bundle
test-arm:
	$(MAKE) test-bundle ARCH=aarch64

test-bundle: $(FAULT_RUN) bundle
	bash tests/bundle/in_debian_root.sh $(ARCH) build/bundle/bogiemon-$$($(TOOLS) -c 'import sys; sys.path.insert(0, "bundle"); import build; print(build.version())')-$(ARCH).tar.gz $(FAULT_RUN)

# The CAN path on a real kernel (not part of `make test`): this machine's kernel has no SocketCAN,
# so Debian's own kernel boots in QEMU (software emulation, about 12x slower than the host) with
# vcan0 up and this checkout, its venv included, shared read-only (tests/vm/: setup.sh once, as
# root, about 90 MB of packages; then run.sh). The `vcan`-marked tests run there: `bogiemon play`
# and can-utils into the CAN source, and the recvmmsg reader against python-can on an AF_CAN socket
# (about 3 minutes; the count is printed).
VM_OUT := build/vm-out
.PHONY: test-vcan vm-setup
vm-setup:
	bash tests/vm/setup.sh

test-vcan: $(STAMP) vm-setup
	mkdir -p $(VM_OUT)
	VM_OUT=$(abspath $(VM_OUT)) bash tests/vm/run.sh "cd $(CURDIR) && PYTHONDONTWRITEBYTECODE=1 $(PY) -m pytest -p no:cacheprovider -m vcan -rA -q tests/drivers/test_vcan.py"

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis .mypy_cache .ruff_cache build *.egg-info
