"""kill -9 of `bogiemon run` with its recorder, on a small disk of its own, at random moments; the
disk then filled to its last page by what bogiemon left (the temporary of a recording killed in the
middle of its write, else a recording); then a start. A crash must never keep the daemon from
starting: the next `bogiemon run` gives back what is its own (daemon/statedir.py), opens the store,
commits the run's events and exits 0.

A few trials here; bench/kill9.py (`make kill9`) runs them by the dozen. The tmpfs needs root
(mount); elsewhere these tests are skipped and say so.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.config import parse_config
from bogiemon.daemon.recorder import NAME_PATTERN
from bogiemon.daemon.statedir import own_kind
from bogiemon.daemon.store import EventStore
from tests.daemon.test_e2e import Daemon
from tests.daemon.test_kill9 import Workload, _Lines, draw_moment, make_workload
from tests.waiting import Progress

DISK_SIZE = "48m"  # the reserve (19.6 MiB), recordings, and what the filler takes
ROOM_FOR_RECORDINGS = 4 << 20  # free above the reserve when the first run starts


def mount_tmpfs(root: Path, size: str = DISK_SIZE) -> str | None:
    """A tmpfs of that size at root (made); None, or why it cannot be mounted here."""
    if os.geteuid() != 0:
        return "mounting a small tmpfs needs root"
    root.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size},mode=0755", "tmpfs", str(root)], capture_output=True, text=True)
    return None if proc.returncode == 0 else f"cannot mount a tmpfs here: {proc.stderr.strip()}"


def unmount(root: Path) -> None:
    subprocess.run(["umount", "-l", str(root)], capture_output=True)


def free_bytes(path: Path) -> int:
    usage = os.statvfs(path)
    return usage.f_bavail * usage.f_frsize


def grow_until_free(path: Path, free: int) -> None:
    """A file grown (appended to) until `free` bytes, to the page, are left on its file system."""
    with path.open("ab") as f:
        while (left := free_bytes(path.parent) - free) > 0:
            f.write(bytes(min(left, 1 << 20)))
            f.flush()


def recorder_config(workload: Workload, state: Path) -> str:
    return workload.run_config(state) + f'[recorder]\nenabled = true\ndirectory = "{state / "recordings"}"\nlead_in_s = 2.0\n'


@dataclass(frozen=True)
class DiskTrialResult:
    after_events: int
    delay_s: float
    completed: bool  # the first run ended by itself before its kill
    left: str  # what bogiemon left that was grown to fill the disk: "recording temporary" or "recording"
    restart_status: int | None  # the start after it: 0, or what it exited with (None: it did not end)
    stored_before: int  # events in the store after the kill
    stored_after: int  # and after the restarted run
    temporaries_left: int  # temporaries of bogiemon's in its folders after the restart
    reserve_free: bool  # the event store's reserve free after the restart
    note: str = ""

    @property
    def ok(self) -> bool:
        return self.restart_status == 0 and self.temporaries_left == 0 and self.reserve_free and self.stored_after >= self.stored_before


def run_disk_trial(workload: Workload, after_events: int, delay_s: float, trial_dir: Path) -> DiskTrialResult:
    """Run with the recorder on a fresh tmpfs, kill -9 delay_s after its after_events-th printed
    event, fill the disk to its last page with what it left, start it again; judge the start."""
    disk = trial_dir / "disk"
    why = mount_tmpfs(disk)
    if why is not None:
        raise RuntimeError(why)
    try:
        state = disk / "state"
        state.mkdir()
        config_text = recorder_config(workload, state)
        reserve = parse_config(config_text, "trial").recorder_settings().reserve_bytes
        grow_until_free(disk / "filler", reserve + ROOM_FOR_RECORDINGS)  # another program's file
        completed = _run_and_kill(trial_dir / "first", config_text, after_events, delay_s)
        stored_before = _stored(state)
        left = _fill_with_what_it_left(state / "recordings")
        (trial_dir / "restart").mkdir()
        restart = Daemon(trial_dir / "restart", config_text)
        restart.sock.close()
        try:
            status, _, err = restart.finish()
        except AssertionError as exc:
            status, err = None, str(exc)
        temporaries = [name for folder in (state, state / "recordings") if folder.exists()
                       for name in os.listdir(folder) if (own_kind(name) or "").endswith("temporary")]  # fmt: skip
        return DiskTrialResult(after_events, delay_s, completed, left, status, stored_before, _stored(state), len(temporaries),
                               free_bytes(disk) >= reserve, note=err.strip().splitlines()[-1] if status else "")  # fmt: skip
    finally:
        unmount(disk)


def _run_and_kill(folder: Path, config_text: str, after_events: int, delay_s: float) -> bool:
    folder.mkdir(parents=True)
    daemon = Daemon(folder, config_text)
    daemon.sock.close()
    lines = _Lines(daemon.proc.stdout, after_events)
    progress = Progress(daemon.proc.pid)
    while not lines.printed.wait(0.2) and progress.working():
        pass
    if delay_s:
        lines.printed.wait(delay_s)  # a pause of delay_s, cut short by nothing: printed is already set
    completed = daemon.proc.poll() is not None
    if not completed:
        daemon.proc.send_signal(signal.SIGKILL)
    daemon.proc.wait()
    lines.join()
    daemon.proc.stderr.close()
    return completed


def _fill_with_what_it_left(recordings: Path) -> str:
    """Grow the largest temporary the kill left, else the newest recording (else a new one) until
    the disk's last page is taken: bogiemon's own files fill it."""
    recordings.mkdir(exist_ok=True)
    names = sorted(os.listdir(recordings))
    temporaries = [n for n in names if own_kind(n) == "recording temporary"]
    own = [n for n in names if NAME_PATTERN.fullmatch(n)]
    if temporaries:
        target, left = max(temporaries, key=lambda n: (recordings / n).stat().st_size), "recording temporary"
    else:
        target, left = (own[-1] if own else "20200101T000000Z_periodic.csv.gz"), "recording"
    grow_until_free(recordings / target, 0)
    return left


def _stored(state: Path) -> int:
    try:
        store = EventStore(state, readonly=True)
    except Exception:  # noqa: BLE001 - no store yet (killed before it was made), or none readable: counted as none
        return 0
    try:
        return store.count()
    finally:
        store.close()


def as_line(result: DiskTrialResult) -> str:
    return json.dumps(vars(result) | {"ok": result.ok})


# --- the tests ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def workload(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Workload]:
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    yield make_workload(tmp_path_factory.mktemp("kill9-disk"))


def test_a_recording_temporary_filling_the_disk_to_its_last_page_never_keeps_run_from_starting(workload: Workload, tmp_path: Path) -> None:
    # The finding: a recording's temporary file, left by a recorder killed in the middle of its write,
    # on a full state disk: before the store opened only finished recordings were given back, and
    # `run` exited 2 at every retry. Here the first run ends by itself and the temporary is made by
    # hand (a kill lands in a write only now and then): the same bytes under a temporary's name.
    disk = tmp_path / "disk"
    why = mount_tmpfs(disk)
    if why is not None:
        pytest.skip(why)
    try:
        state = disk / "state"
        (state / "recordings").mkdir(parents=True)
        config_text = recorder_config(workload, state)
        temporary = state / "recordings" / ".0badf00d.20200201T000000Z_confirmed.csv.gz"
        EventStore(state).close()
        grow_until_free(temporary, 0)
        with pytest.raises(Exception, match="is full, 0 KiB free"):
            EventStore(state)  # as it is, the store cannot even open
        (tmp_path / "run").mkdir()
        daemon = Daemon(tmp_path / "run", config_text)
        daemon.sock.close()
        status, out, err = daemon.finish()
        assert status == 0, err
        assert not temporary.exists() and _stored(state) == len(workload.events)
        assert '"deleted what a killed writer left half-written"' in out
    finally:
        unmount(disk)


@pytest.mark.slow
def test_kill_9_of_run_with_its_recorder_then_a_disk_full_of_what_it_left_never_keeps_the_next_start_from_committing(
    workload: Workload, tmp_path: Path
) -> None:
    rng = np.random.default_rng(11)
    results = [run_disk_trial(workload, *draw_moment(rng, workload), tmp_path / f"trial{i}") for i in range(3)]
    assert [as_line(r) for r in results if not r.ok] == []
