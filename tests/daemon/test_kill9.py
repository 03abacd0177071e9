"""kill -9 at random moments of `bogiemon replay` and `bogiemon run`, real processes on a real
SQLite store: the store always opens, no committed event is lost or duplicated, and the alarm
state after a restart is the one committed last.

A handful of trials here; bench/kill9.py (`make kill9`) runs the same trials by the hundred.
Every trial replays one recording with many alarms through the process and kills it at a seeded
random moment: a random time into its start-up, or a random delay after a random number of
printed events (so that kills land all along the run however busy the machine). An event counts as committed once the process printed it (both commands
report an event only after its commit); what it printed must be in the store, in order, and the
store must hold a prefix of the uninterrupted run's events (at most one window's events beyond
what was printed: those committed but not yet printed). The state in the store must be the one
the uninterrupted run committed with its last stored event, or its final one, and a restarted
monitor (and a restarted `bogiemon run`) must start from it.
"""

from __future__ import annotations

import json
import shutil
import signal
import sqlite3
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bogiemon.daemon.config import BogiemonConfig, ReplaySourceConfig, parse_config
from bogiemon.judgement.events import Event
from bogiemon.daemon.monitor import STATE_KEY, Monitor
from bogiemon.daemon.sources import open_source
from bogiemon.daemon.store import EventStore, StoreError
from bogiemon.drivers.base import EndOfStream
from bogiemon.drivers.recording import write_csv_recording
from tests.daemon.synthetic import FS_HZ, bogie_accel, short_windows_config
from tests.daemon.test_e2e import BOGIEMON, Daemon

KINDS = ("replay", "run")
START_S = 1.7e9


def _plain(value: Any) -> Any:
    """A state as the store gives it back (JSON), for comparing."""
    return json.loads(json.dumps(value))


class _RecordingStore(EventStore):
    """The store of the uninterrupted reference run: remembers each commit's events and state."""

    def __init__(self, state_dir: Path) -> None:
        super().__init__(state_dir)
        self.commits: list[tuple[list[tuple[float, str]], Any]] = []

    def append(self, events: list[Event], state: dict[str, Any] | None = None) -> None:
        super().append(events, state)
        self.commits.append(([(e.time_s, e.kind.value) for e in events], _plain((state or {}).get(STATE_KEY))))


@dataclass
class Workload:
    """One recording with many alarm cycles, its configs, and what an uninterrupted run commits."""

    workdir: Path
    recording: Path
    replay_config: Path
    config: BogiemonConfig
    batches: list[list[tuple[float, str]]] = field(default_factory=list)  # the events of each commit
    states: list[Any] = field(default_factory=list)  # the state committed with each of those batches
    final_state: Any = None  # what save_state() commits at the end

    @property
    def events(self) -> list[tuple[float, str]]:
        return [key for batch in self.batches for key in batch]

    def run_config(self, state_dir: Path) -> str:
        return short_windows_config(clear_after_windows=1, state_dir=state_dir) + (
            f'[source]\nkind = "replay"\npath = "{self.recording}"\nrealtime = false\n'
        )


def make_workload(workdir: Path, cycles: int = 12, seed: int = 7) -> Workload:
    """cycles of a coupled (faulty) stretch and a healthy one: SUSPECTED, CONFIRMED, CLEARED each."""
    workdir.mkdir(parents=True, exist_ok=True)
    parts = []
    for i in range(cycles):
        parts += [bogie_accel(14, seed + 2 * i, pitch_roll_coupling=1.0), bogie_accel(14, seed + 2 * i + 1)]
    accel = np.concatenate(parts)
    recording = workdir / "cycles.csv"
    write_csv_recording(recording, START_S + np.arange(accel.shape[0]) / FS_HZ, accel)
    text = short_windows_config(clear_after_windows=1)
    replay_config = workdir / "replay.toml"
    replay_config.write_text(text)
    config = parse_config(text, str(replay_config))
    workload = Workload(workdir, recording, replay_config, config)
    # The reference: the same source and monitor in this process, without a kill.
    store = _RecordingStore(workdir / "reference")
    source = open_source(config.model_copy(update={"source": ReplaySourceConfig(kind="replay", path=str(recording), realtime=False)}))
    monitor = Monitor(config.monitor_settings(None, source.fs_hz), store)
    while True:
        try:
            block = source.read(1.0)
        except EndOfStream:
            break
        if block is not None:
            monitor.feed(block)
    source.close()
    monitor.save_state()
    store.close()
    *event_commits, final = store.commits
    workload.batches = [keys for keys, _ in event_commits]
    workload.states = [state for _, state in event_commits]
    workload.final_state = final[1]
    return workload


@dataclass(frozen=True)
class TrialResult:
    kind: str
    after_events: int  # killed delay_s after the process printed this many events
    delay_s: float
    completed: bool  # the process ended by itself before the kill
    reported: int  # events the process printed (so committed) before it died
    stored: int
    store_opened: bool
    lost: int  # printed (so committed) but not in the store; committed and unprinted beyond one window
    duplicated: int  # an event (window time and kind) twice in the store
    unlike_reference: int  # stored events that are not the uninterrupted run's, in its order
    state_mismatch: bool  # the stored state is not the one committed with the last stored event
    restart_mismatch: bool  # a restarted monitor, or `bogiemon run`, starts from another state
    note: str = ""

    @property
    def ok(self) -> bool:
        return self.store_opened and not (self.lost or self.duplicated or self.unlike_reference or self.state_mismatch or self.restart_mismatch)


class _Lines:
    """A process's stdout, read line by line in a thread so that it never blocks on a full pipe;
    `printed` is set once it printed the given number of events."""

    def __init__(self, stream: Any, after_events: int) -> None:
        self.lines: list[str] = []
        self.printed = threading.Event()
        self._after_events = after_events
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream: Any) -> None:
        events = 0
        if self._after_events == 0:
            self.printed.set()
        for line in stream:
            self.lines.append(line)
            if '"event_id"' in line:
                events += 1
                if events >= self._after_events:
                    self.printed.set()
        self.printed.set()  # the process ended

    def join(self) -> list[str]:
        self._thread.join(10)
        return self.lines


def _reported_ids(kind: str, lines: list[str]) -> list[str]:
    """The events a process printed: JSON lines (replay --json) or JSON log lines after "<N>" (run)."""
    ids = []
    for line in lines:
        if not line.endswith("\n") or '"event_id"' not in line:
            continue  # a line cut by the kill was not (wholly) reported
        text = line[3:] if kind == "run" else line
        ids.append(json.loads(text)["event_id"])
    return ids


def run_trial(workload: Workload, kind: str, after_events: int, delay_s: float, trial_dir: Path) -> TrialResult:
    """Start `bogiemon <kind>` on the recording and kill -9 it delay_s after it printed its
    after_events-th event (after_events 0: delay_s after its start); judge what it left.

    Kills timed by the events printed, not by the clock alone, land all along the run however
    busy the machine is; the random delay puts them anywhere between two commits."""
    state = trial_dir / "state"
    trial_dir.mkdir(parents=True)
    if kind == "run":
        daemon = Daemon(trial_dir, workload.run_config(state))
        proc = daemon.proc
        daemon.sock.close()  # the notify socket: nothing here listens
    else:
        proc = subprocess.Popen(
            [*BOGIEMON, "replay", str(workload.recording), "--config", str(workload.replay_config), "--state-dir", str(state), "--json"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
    lines = _Lines(proc.stdout, after_events)
    lines.printed.wait(120)
    time.sleep(delay_s)
    completed = proc.poll() is not None
    if not completed:
        proc.send_signal(signal.SIGKILL)
    proc.wait(30)
    stderr = proc.stderr.read()
    proc.stderr.close()
    reported = _reported_ids(kind, lines.join())
    if completed and proc.returncode != 0:
        raise AssertionError(f"{kind} failed by itself ({proc.returncode}) in {trial_dir}: {stderr}")
    return judge(workload, kind, after_events, delay_s, completed, reported, state, trial_dir)


def draw_moment(rng: np.random.Generator, workload: Workload) -> tuple[int, float]:
    """A random moment of a run: after how many printed events, and how long after it."""
    if rng.random() < 0.2:  # one kill in five in the start-up: imports, creating or opening the store
        return 0, float(rng.uniform(0.0, 1.5))
    return int(rng.integers(1, len(workload.events) + 1)), float(rng.uniform(0.0, 0.1))


def judge(
    workload: Workload, kind: str, after_events: int, delay_s: float, completed: bool, reported: list[str], state: Path, trial_dir: Path
) -> TrialResult:
    def result(**fields: Any) -> TrialResult:
        base = dict(kind=kind, after_events=after_events, delay_s=delay_s, completed=completed, reported=len(reported), stored=0, store_opened=True, lost=0,
                    duplicated=0, unlike_reference=0, state_mismatch=False, restart_mismatch=False)  # fmt: skip
        return TrialResult(**{**base, **fields})

    try:
        store = EventStore(state)  # as the restarted daemon opens it: checked, then writable
    except StoreError as exc:
        return result(store_opened=False, lost=len(reported), note=str(exc))
    try:
        events = store.events()
        saved = store.get_state(STATE_KEY)
        restarted = Monitor(workload.config.monitor_settings(), store)
    finally:
        store.close()
    ids = [e.event_id for e in events]
    keys = [(e.time_s, e.kind.value) for e in events]
    reference = workload.events
    lost = len(set(reported) - set(ids))
    duplicated = len(keys) - len(set(keys))
    unlike = sum(1 for i, key in enumerate(keys) if i >= len(reference) or reference[i] != key)
    unprinted = keys[len(reported) :]
    if len({time_s for time_s, _ in unprinted}) > 1:  # more than the window being printed at the kill
        lost += len(unprinted)
    # The state must be the one committed with the last stored batch (or the final one).
    boundaries = {sum(len(b) for b in workload.batches[: j + 1]): workload.states[j] for j in range(len(workload.batches))}
    expected = [boundaries[len(keys)]] if len(keys) in boundaries else ([None] if not keys else [])
    if len(keys) == len(reference):
        expected.append(workload.final_state)
    state_mismatch = _plain(saved) not in expected
    restart_mismatch = saved is not None and _plain(restarted.state_dict()) != _plain(saved)
    note = ""
    if kind == "run" and not state_mismatch:
        mode = _restarted_run_mode(workload, trial_dir)
        expected_mode = (saved or {}).get("decision", {}).get("mode", "normal")
        if mode != expected_mode:
            restart_mismatch, note = True, f"bogiemon run restarted in mode {mode}, the store says {expected_mode}"
    return result(stored=len(keys), lost=lost, duplicated=duplicated, unlike_reference=unlike, state_mismatch=state_mismatch,
                  restart_mismatch=restart_mismatch, note=note)  # fmt: skip


def _restarted_run_mode(workload: Workload, trial_dir: Path) -> str | None:
    """The mode a restarted `bogiemon run` says it starts in (its "starting" line), then kill it."""
    restart_dir = trial_dir / "restart"
    restart_dir.mkdir()
    daemon = Daemon(restart_dir, workload.run_config(trial_dir / "state"))
    daemon.sock.close()
    mode = None
    try:
        for line in daemon.proc.stdout:
            if '"starting"' in line:
                mode = json.loads(line[3:])["mode"]
                break
    finally:
        daemon.proc.send_signal(signal.SIGKILL)
        daemon.proc.wait(30)
        daemon.proc.stdout.close()
        daemon.proc.stderr.close()
    return mode


@pytest.fixture(scope="module")
def workload(tmp_path_factory: pytest.TempPathFactory) -> Workload:
    return make_workload(tmp_path_factory.mktemp("kill9"))


def test_the_workload_commits_every_alarm_cycle_and_its_state_with_each_batch(workload: Workload) -> None:
    kinds = [kind for _, kind in workload.events]
    assert kinds == ["SUSPECTED", "CONFIRMED", "CLEARED"] * 12
    assert len(workload.states) == len(workload.batches) and workload.final_state is not None
    assert [state["decision"]["mode"] for state in workload.states[:3]] == ["suspected", "confirmed", "normal"]


@pytest.mark.slow
@pytest.mark.parametrize("kind", KINDS)
def test_kill_9_at_random_moments_loses_or_duplicates_no_committed_event_and_restarts_in_the_committed_state(
    workload: Workload, kind: str, tmp_path: Path
) -> None:
    rng = np.random.default_rng(9 if kind == "replay" else 10)
    results = [run_trial(workload, kind, *draw_moment(rng, workload), tmp_path / f"trial{i}") for i in range(3)]
    assert [r for r in results if not r.ok] == []
    assert sum(r.reported for r in results) > 0  # the kills landed while events were being committed


def test_the_judge_counts_a_lost_event_a_duplicate_and_a_state_that_is_not_the_committed_one(workload: Workload, tmp_path: Path) -> None:
    reference = workload.workdir / "reference"
    store = EventStore(reference, readonly=True)
    printed = [e.event_id for e in store.events()]
    store.close()
    for name in ("lost", "duplicated", "state"):
        shutil.copytree(reference, tmp_path / name)
    with sqlite3.connect(tmp_path / "lost" / "events.sqlite3") as db:
        db.execute("DELETE FROM events WHERE seq = 5")
    with sqlite3.connect(tmp_path / "duplicated" / "events.sqlite3") as db:
        db.execute("INSERT INTO events (event_id, time_s, kind, severity, config_hash, body) SELECT 'again', time_s, kind, severity, config_hash, "
                   "json_set(body, '$.event_id', 'again') FROM events WHERE seq = 36")  # fmt: skip
    with sqlite3.connect(tmp_path / "state" / "events.sqlite3") as db:
        db.execute("UPDATE state SET value = ? WHERE key = ?", (json.dumps(workload.states[0]), STATE_KEY))
    intact = judge(workload, "replay", 36, 0.0, True, printed, reference, tmp_path)
    lost = judge(workload, "replay", 36, 0.0, True, printed, tmp_path / "lost", tmp_path)
    duplicated = judge(workload, "replay", 36, 0.0, True, [*printed, "again"], tmp_path / "duplicated", tmp_path)
    state = judge(workload, "replay", 36, 0.0, True, printed, tmp_path / "state", tmp_path)
    assert intact.ok and intact.stored == 36
    assert (lost.lost, lost.duplicated, lost.unlike_reference) == (1, 0, 31)
    assert (duplicated.lost, duplicated.duplicated, duplicated.unlike_reference) == (0, 1, 1)
    assert (state.lost, state.state_mismatch, state.restart_mismatch) == (0, True, False)
