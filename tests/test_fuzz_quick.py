"""The fuzz suite's short run (bench/fuzz.py --quick, the CI run of issue 17): a few thousand inputs per
target through every decoder and parser, in a subprocess, as `make fuzz` runs them.

The slow tier (tests/tier.py): `make test-slow` runs the whole quick run; `make test` keeps its
first third of every target's inputs (--share: input i is seeded by i alone, so these are the quick
run's first inputs), 1000 for the decoders of 3000, 334 for those of 1000.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.tier import sized
from tests.waiting import Progress

REPO = Path(__file__).resolve().parents[1]
FUZZ = REPO / "bench" / "fuzz.py"
# Every decoder and parser issue 17 names: the CAN frame decoder in both layouts, the serial packet
# parser and source, the CSV reader, the CAN log readers, the config loader, the MQTT schema and the
# listener, the publisher's outbox and the event store's reader.
DECODERS = {"can-hub", "can-per-node", "serial-parser", "serial-source", "csv", "canlog-log", "canlog-asc", "canlog-blf",
            "canlog-trc", "canlog-pycsv", "config", "mqtt-schema", "mqtt-listen", "outbox", "store"}  # fmt: skip
# What issue 27 reached: compressed and Parquet recordings, the recorder on a full disk, reloads; and
# floods of signals at a `bogiemon run` process. One input of these is a whole file or a daemon's
# run: their quick run is a few hundred, a dozen or a few.
# Issue 37's formats: python-can's SQLite logs, MF4 bus logs and signals, other writers' CSV through a mapping.
HOSTILE = {"recording-gz": 200, "recording-parquet": 200, "recorder-disk": 20, "reload": 12, "signals": 4,
           "canlog-sqlite": 300, "mf4": 100, "recording-mapped": 300}  # fmt: skip
TARGETS = DECODERS | set(HOSTILE)
# The quick run takes about four minutes alone, and several times that on a busy machine (over 20
# minutes at a load average of 25): it is waited for while its harness works (tests/waiting.py),
# which ends every input itself (a CPU-time limit, workers killed past it); the backstop only
# catches a harness that stopped.
STALL_S, BACKSTOP_S = 120.0, 4 * 3600.0
SHARE = sized(1 / 3, 1.0)


def share(count: int) -> int:
    """What --share SHARE makes of a target's count."""
    return max(1, math.ceil(SHARE * count))


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[subprocess.CompletedProcess[str], dict[str, Any]]:
    folder = tmp_path_factory.mktemp("fuzz")
    figures = folder / "fuzz.json"
    args = [sys.executable, str(FUZZ), "--quick", "--share", repr(SHARE), "--json", str(figures), "--crash-dir", str(folder / "crashes")]
    proc = subprocess.Popen(args, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    progress = Progress(proc.pid, STALL_S, BACKSTOP_S)
    while True:
        try:
            stdout, stderr = proc.communicate(timeout=1.0)  # reads its pipes meanwhile, keeps what it read
            break
        except subprocess.TimeoutExpired:
            if not progress.working():
                proc.kill()
                stdout, stderr = proc.communicate()
                break
    done = subprocess.CompletedProcess(args, proc.returncode, stdout, stderr)
    assert figures.exists(), f"the fuzz run wrote no figures (exit status {done.returncode}):\n{done.stderr[-4000:]}"
    return done, json.loads(figures.read_text())


@pytest.mark.slow
@pytest.mark.slow_tier
def test_the_quick_fuzz_run_covers_every_target_with_its_quick_count(quick_run: tuple[subprocess.CompletedProcess[str], dict[str, Any]]) -> None:
    _, figures = quick_run
    assert TARGETS <= set(figures["targets"])
    decoders = {name: figures["targets"][name]["inputs"] >= share(1000) for name in DECODERS}
    assert decoders == dict.fromkeys(DECODERS, True)
    # The recorder's target mounts a tmpfs: where that is not allowed (not root) it says so and runs nothing.
    hostile = {name: figures["targets"][name]["inputs"] if figures["targets"][name]["unavailable"] is None else share(n) for name, n in HOSTILE.items()}
    assert hostile == {name: share(n) for name, n in HOSTILE.items()}


@pytest.mark.slow
@pytest.mark.slow_tier
def test_the_quick_fuzz_run_finds_no_crash_and_no_hang(quick_run: tuple[subprocess.CompletedProcess[str], dict[str, Any]]) -> None:
    done, figures = quick_run
    found = {name: {"crashes": t["crashes"], "hangs": t["hangs"]} for name, t in figures["targets"].items() if t["crashes"] or t["hangs"]}
    assert found == {}, done.stdout[-6000:]
    assert done.returncode == 0
