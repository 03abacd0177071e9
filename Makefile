# bogiemon: `make demo` and `make test` work on a fresh clone with python3 and make.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp

.PHONY: demo test install bench bench-core bench-drivers bench-simulator clean

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
test: $(STAMP)
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

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis build *.egg-info
