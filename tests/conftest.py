"""What every test process shares, and how `make test` spreads the suite over pytest-xdist's workers.

Every test process, and every process it starts, runs OpenBLAS on one thread and lets OpenMP's
(numba's) idle threads sleep: otherwise OpenBLAS's second thread spins after every small call, a
core burnt for nothing (tests/lab/test_robust.py alone: 46 s of CPU, 23 s on one thread), and the
workers are the parallelism. The gateway's unit and the Dask workers run OpenBLAS so too.

Under `-n N --dist loadgroup --no-loadscope-reorder` only (a plain `pytest` runs as before):

- A unit of work: tests that share a module-scoped fixture (a simulated fleet, the quick study or
  transfer, the container's boot, a Dask cluster, the browser) form one `xdist_group`, so that one
  worker computes the fixture once instead of every worker that draws one of its tests; every
  other test is a unit of its own.
- The longest units start first, so that none starts last and keeps the run waiting for it alone:
  those in LONGEST (their measured seconds, longest first), then the other units with a `slow`
  test, then the other groups, then the rest, each in collection order (xdist hands the units out
  in this order). A stale figure in LONGEST changes the order only, never what runs.
- The simulator's compiled kernels (models A and B, simulator/kernel.py) are compiled once, into
  numba's cache, by two processes the controller starts while the workers collect; each worker
  waits for them before its first test instead of compiling the same kernels itself (about 40 s
  of CPU per worker on a fresh clone, as in CI; a few seconds when the cache is warm).
"""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, settings

# Set before numpy is first imported (OpenBLAS reads it when it loads); a value given outside wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_WAIT_POLICY", "passive")

# No hypothesis example has a deadline, and slow data generation is no failure: both are wall-clock
# limits, and under `make test`'s load an example of 85 ms took 253 ms and failed its 200 ms
# (tests/lab/test_study.py's ROC AUC). Timing is measured in bench/, never asserted in a test.
settings.register_profile("bogiemon", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("bogiemon")

# The controller tells the workers where the compile's lock is (the workers inherit its environment).
KERNEL_LOCK_ENV = "BOGIEMON_TEST_KERNEL_LOCK"
# One short simulation per wagon model: the same entry point as the tests, so the same signatures.
COMPILE_KERNEL = (
    "from bogiemon.simulator.run import simulate; from bogiemon.simulator.scenario import Scenario; "
    "simulate(Scenario(duration_s=1.0, model={model!r}))"
)


# Units that took 20 s or more in one process (`pytest --durations`, 2026-12-03, on two busy cores;
# tests/daemon/test_calibrate.py's 62 s then was the kernels' compile, now done before the tests):
# a group by its name (the module of the fixture its tests share), a test of its own by a prefix of
# its node id.
LONGEST = {
    "tests/lab/test_transfer.py": 160,  # the quick transfer's two tests
    "tests/lab/test_study.py": 128,
    "tests/fleet/test_fleet_demo.py": 128,
    "tests/test_fuzz_quick.py": 115,
    "tests/lab/test_transfer.py::test_a_wagon_30_percent_off": 108,
    "tests/lab/test_evaluation.py": 85,
    "tests/fleet/test_fleet_pipeline.py": 77,
    "tests/lab/test_fleetsim.py": 48,
    "tests/systemd/test_system.py": 33,
    "tests/lab/test_robust.py": 28,
    "tests/daemon/test_sensor_scenarios.py": 27,
    "tests/daemon/test_service.py::test_sighup_after_include_5": 21,
}


def _is_worker(config: pytest.Config) -> bool:
    return hasattr(config, "workerinput")


def _is_controller(config: pytest.Config) -> bool:
    return not _is_worker(config) and bool(getattr(config.option, "numprocesses", None)) and config.getoption("dist", "no") != "no"


_COMPILERS = pytest.StashKey[tuple[list[subprocess.Popen[bytes]], str]]()


def pytest_configure(config: pytest.Config) -> None:
    if not _is_controller(config):
        return
    fd, lock_path = tempfile.mkstemp(prefix="bogiemon-kernel-compile-", suffix=".lock")
    fcntl.flock(fd, fcntl.LOCK_EX)
    # The compiling processes inherit the locked file: the lock is released when the last of them ends.
    # Should one fail, the workers compile what they need themselves, as without this.
    compilers = [
        subprocess.Popen([sys.executable, "-c", COMPILE_KERNEL.format(model=model)], pass_fds=(fd,),
                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for model in ("a", "b")
    ]  # fmt: skip
    os.close(fd)
    os.environ[KERNEL_LOCK_ENV] = lock_path
    config.stash[_COMPILERS] = (compilers, lock_path)


def pytest_unconfigure(config: pytest.Config) -> None:
    compilers, lock_path = config.stash.get(_COMPILERS, ([], ""))
    for proc in compilers:  # long done, unless the run was cut short
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    if lock_path:
        os.unlink(lock_path)


@pytest.fixture(scope="session", autouse=True)
def _simulator_kernels_compiled() -> Iterator[None]:
    """In an xdist worker: wait until the controller's compile of the kernels has ended (its lock)."""
    lock_path = os.environ.get(KERNEL_LOCK_ENV)
    if lock_path and os.path.exists(lock_path):
        with open(lock_path) as lock:
            fcntl.flock(lock, fcntl.LOCK_SH)
    yield


def _shares_a_module_fixture(item: pytest.Item) -> bool:
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return False
    return any(defs and defs[-1].scope in ("module", "package", "class") for defs in info.name2fixturedefs.values())


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook reads the xdist_group marks
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not _is_worker(config):
        return
    unit: dict[str, str] = {}
    for item in items:
        if _shares_a_module_fixture(item) and not any(item.iter_markers("xdist_group")):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::", 1)[0]))
        groups = sorted(str(m.args[0] if m.args else m.kwargs.get("name", "default")) for m in item.iter_markers("xdist_group"))
        unit[item.nodeid] = "_".join(groups) if groups else item.nodeid
    seconds = {u: float(LONGEST.get(u, 0.0)) for u in unit.values()}
    for item in items:
        if unit[item.nodeid] == item.nodeid:  # a test of its own
            seconds[item.nodeid] = max((s for prefix, s in LONGEST.items() if "::" in prefix and item.nodeid.startswith(prefix)), default=0.0)
    slow_units = {unit[item.nodeid] for item in items if any(item.iter_markers("slow"))}
    grouped_units = {unit[item.nodeid] for item in items if unit[item.nodeid] != item.nodeid}

    def rank(item: pytest.Item) -> tuple[float, int]:
        u = unit[item.nodeid]
        return -seconds[u], 0 if u in slow_units else 1 if u in grouped_units else 2

    items.sort(key=rank)  # stable: collection order within each rank, the same on every worker


@pytest.hookimpl(trylast=True)
def pytest_collection_finish(session: pytest.Session) -> None:
    """In a worker under --dist loadgroup: a grouped test whose node id lacks its group's suffix
    would be spread like any other (pytest 9.2 with xdist 3.8): stop rather than run without groups."""
    if not _is_worker(session.config) or not session.config.getvalue("loadgroup"):
        return
    lost = [item.nodeid for item in session.items if any(item.iter_markers("xdist_group")) and "@" not in item.nodeid.rpartition("]")[2]]
    if lost:
        raise pytest.UsageError(
            f"xdist's loadgroup did not take the group of {len(lost)} tests (e.g. {lost[0]}): "
            "this pytest and pytest-xdist do not go together (pytest-xdist issue 1386); see pyproject.toml's test extra"
        )
