"""One truth about a config and the files it names (daemon/startup.py): check-config refuses what
`run` refuses at its start and accepts what it starts; a reload compares the config and every file
it names, and applies or rejects them together."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import structlog
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.daemon.config import load_config_and_files
from bogiemon.daemon.notify import Notifier
from bogiemon.daemon.service import Service
from bogiemon.daemon.sources import open_source
from bogiemon.daemon.startup import Snapshot, check_start
from bogiemon.drivers.base import Block, EndOfStream, HealthCounters, Source
from bogiemon.drivers.candb import load_layout
from bogiemon.drivers.player import write_can_log
from bogiemon.drivers.recording import write_csv_recording
from bogiemon.judgement.models import FUSED_MODEL_FILE, LOAD_MODEL_FILE
from tests.daemon.synthetic import FS_HZ, as_blocks, bogie_accel, short_windows_config

BOGIEMON = [sys.executable, "-m", "bogiemon.cli.main"]
SHIPPED_DBC = Path(str(resources.files("bogiemon.config").joinpath("bogiemon.dbc")))
SHIPPED_MODELS = Path(str(resources.files("bogiemon.config")))
OTHER_DBC = 'VERSION ""\n\nBO_ 1280 Other: 8 Vector__XXX\n SG_ Value : 0|8@1+ (1,0) [0|255] "" Vector__XXX\n'
ACCEL = bogie_accel(8, seed=4)


def write_dbc(path: Path, state: str) -> None:
    if state == "shipped":
        shutil.copyfile(SHIPPED_DBC, path)
    elif state == "other":  # a valid DBC without the hub's message
        path.write_text(OTHER_DBC)
    elif state == "garbage":
        path.write_text("BO_ this is no DBC\n\x00\x01")
    elif state == "folder":
        path.mkdir()
    # "missing": nothing


def write_recording(path: Path, state: str, folder: Path) -> None:
    time_s = 1.7e9 + np.arange(ACCEL.shape[0]) / FS_HZ
    if state == "csv":
        write_csv_recording(path, time_s, ACCEL)
    elif state == "csv-200hz":  # a rate the config's 6 s windows of 2 s hops at 100 Hz take too
        write_csv_recording(path, 1.7e9 + np.arange(ACCEL.shape[0]) / 200.0, ACCEL)
    elif state == "csv-7hz":  # a rate its filters cannot run at
        write_csv_recording(path, 1.7e9 + np.arange(ACCEL.shape[0]) / 7.0, ACCEL)
    elif state == "bad-header":
        path.write_text("t,x,y,z\n0,1,2,3\n")
    elif state == "empty":
        path.write_bytes(b"")
    elif state == "log":
        write_can_log(path, load_layout(None, "hub"), ACCEL, FS_HZ, start_s=1.7e9)
    elif state == "folder":
        path.mkdir()
    # "missing": nothing


def config_of(folder: Path, recording: str, dbc: str | None, models: str | None) -> Path:
    """A config replaying the recording (as a .log when it is one), naming the DBC and the models folder."""
    suffix = ".log" if recording == "log" else ".csv"
    path = folder / f"run{suffix}"
    write_recording(path, recording, folder)
    text = short_windows_config(state_dir=folder / "state") + f'[source]\nkind = "replay"\npath = "{path}"\nrealtime = false\n'
    if dbc is not None:
        write_dbc(folder / "bus.dbc", dbc)
        text += f'dbc_path = "{folder / "bus.dbc"}"\n'
    if models is not None:
        models_dir = folder / "models"
        models_dir.mkdir()
        for name in (LOAD_MODEL_FILE, FUSED_MODEL_FILE):
            shutil.copyfile(SHIPPED_MODELS / name, models_dir / name)
        if models == "damaged":
            (models_dir / FUSED_MODEL_FILE).write_text("[full]\nfeatures = 5\n")
        text = text.replace("[decision]\n", f'[decision]\nmodels_dir = "{models_dir}"\n', 1)
    config = folder / "bogiemon.toml"
    config.write_text(text)
    return config


def outcome(call: Any) -> tuple[str, str] | None:
    """None, or the user error the call raised (its class and message)."""
    from bogiemon.cli.main import is_user_error

    try:
        call()
    except Exception as exc:  # noqa: BLE001 - any user error, compared below; a bug propagates
        if not is_user_error(exc):
            raise
        return type(exc).__name__, str(exc)
    return None


def check_config(config: Path) -> tuple[str, str] | None:
    def check() -> None:
        check_start(load_config_and_files(config)[0])

    return outcome(check)


def run(config: Path) -> tuple[str, str] | None:
    def start_and_run() -> None:
        with structlog.testing.capture_logs():
            assert Service(config, open_source, sinks=[]).run() == 0  # a recording: it runs to its end

    return outcome(start_and_run)


@settings(max_examples=15)
@given(
    recording=st.sampled_from(["csv", "csv-200hz", "csv-7hz", "bad-header", "empty", "log", "folder", "missing"]),
    dbc=st.sampled_from([None, "shipped", "other", "garbage", "folder", "missing"]),
    models=st.sampled_from([None, "copy", "damaged"]),
)
def test_check_config_refuses_exactly_what_run_refuses_to_start_whatever_the_files_it_names(
    recording: str, dbc: str | None, models: str | None
) -> None:
    with tempfile.TemporaryDirectory() as scratch:
        config = config_of(Path(scratch), recording, dbc, models)
        checked = check_config(config)
        assert checked == run(config)
        if recording == "log" and dbc in ("other", "garbage", "folder", "missing"):
            assert checked is not None and checked[0] in ("DbcError", "ConfigError")


@pytest.mark.parametrize(
    ("recording", "dbc", "named"),
    [
        ("log", "missing", "bus.dbc: cannot read the DBC file"),
        ("log", "folder", "bus.dbc: cannot read the DBC file"),
        ("log", "garbage", "bus.dbc: not a valid DBC file"),
        ("missing", None, "run.csv"),
    ],
)
def test_check_config_exits_2_where_run_exits_2_at_once(tmp_path: Path, recording: str, dbc: str | None, named: str) -> None:
    # The finding: check-config exited 0 where run exited 2 at once (a missing, folder or invalid
    # dbc_path; a missing replay path).
    config = config_of(tmp_path, recording, dbc, None)
    checked = subprocess.run([*BOGIEMON, "check-config", str(config)], capture_output=True, text=True)
    ran = subprocess.run([*BOGIEMON, "run", "--config", str(config)], capture_output=True, text=True)
    assert (checked.returncode, ran.returncode) == (2, 2)
    assert named in checked.stderr and checked.stderr.splitlines()[-1] == ran.stderr.splitlines()[-1]
    assert "Traceback" not in checked.stderr + ran.stderr


# --- a snapshot: the config and its files, part by part --------------------------------------------


@settings(max_examples=40)
@given(st.sets(st.sampled_from(["dbc", "models", "include", "recording", "value"])))
def test_a_snapshot_says_which_sections_changed_with_the_files_they_name(edits: set[str]) -> None:
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        config_path = config_of(folder, "log", "shipped", "copy")
        (folder / "calibration.toml").write_text("[decision]\nconfirm_k = 2\n")
        config_path.write_text('include = ["calibration.toml"]\n' + config_path.read_text())
        before = Snapshot.of(*load_config_and_files(config_path))
        if "dbc" in edits:
            with (folder / "bus.dbc").open("a") as f:
                f.write("\n")  # a valid edit: the same messages
        if "models" in edits:
            with (folder / "models" / LOAD_MODEL_FILE).open("a") as f:
                f.write("\n# refitted\n")
        if "include" in edits:
            (folder / "calibration.toml").write_text("[decision]\nconfirm_k = 3\n")
        if "recording" in edits:
            write_can_log(folder / "run.log", load_layout(None, "hub"), ACCEL[::-1], FS_HZ, start_s=1.7e9)
        if "value" in edits:
            config_path.write_text(config_path.read_text().replace("max_lag_s = 1.0", "max_lag_s = 0.5"))
        after = Snapshot.of(*load_config_and_files(config_path))
        section = {"dbc": "source", "models": "decision", "include": "decision", "recording": "source", "value": "processing"}
        assert before.changed(after) == {section[e] for e in edits}
        assert (before.digest == after.digest) == (not edits)


def test_a_file_rewritten_with_the_same_bytes_is_no_change(tmp_path: Path) -> None:
    config_path = config_of(tmp_path, "log", "shipped", None)
    before = Snapshot.of(*load_config_and_files(config_path))
    text = (tmp_path / "bus.dbc").read_bytes()
    os.unlink(tmp_path / "bus.dbc")
    (tmp_path / "bus.dbc").write_bytes(text)  # another inode, the same content
    config_path.write_text(config_path.read_text() + "# a comment: the same values\n")
    assert before.changed(Snapshot.of(*load_config_and_files(config_path))) == frozenset()


# --- a reload: the config and its files, applied or rejected together ------------------------------


class ReloadNotifier(Notifier):
    """Keeps what the service tells systemd after a reload (READY=1 with its STATUS)."""

    def __init__(self) -> None:
        super().__init__({})
        self.answers: list[str] = []
        self.answered = threading.Event()

    def ready(self, status: str | None = None) -> bool:
        if status is not None and status.startswith("reload"):
            self.answers.append(status)
            self.answered.set()
        return False


class EditingSource(Source):
    """The blocks of a recording; before block `at` an edit of a file, a reload, and a wait for its answer."""

    finite = True

    def __init__(self, blocks: list[Block], at: int, edit: Callable[[], None], service: Callable[[], Service]) -> None:
        self.fs_hz = FS_HZ
        self.counters = HealthCounters()
        self.blocks, self.at, self.edit, self.service = blocks, at, edit, service
        self.next = 0
        self.opened = 0

    def read(self, timeout_s: float) -> Block | None:
        if self.next >= len(self.blocks):
            raise EndOfStream
        if self.next == self.at:
            self.at = -1
            self.edit()
            service = self.service()
            assert isinstance(service.notifier, ReloadNotifier)
            service.request_reload()
            assert service.notifier.answered.wait(60)
        self.next += 1
        return self.blocks[self.next - 1]


def reload_after_editing(tmp_path: Path, edit: Callable[[Path], None]) -> tuple[Service, list[str], int, list[Any]]:
    """A service on a CAN source of the config's DBC and models; before block 10 `edit` changes a
    file in tmp_path and the service reloads. Returns the service, its answers to systemd, how
    many times it opened its source and its log."""
    config_path = config_of(tmp_path, "csv", "shipped", "copy")
    text = config_path.read_text()
    config_path.write_text(text[: text.index("[source]")] + f'[source]\nkind = "can"\ndbc_path = "{tmp_path / "bus.dbc"}"\n')
    blocks = as_blocks(bogie_accel(20, seed=1))
    service: Service
    feed = EditingSource(blocks, 10, lambda: edit(tmp_path), lambda: service)
    layouts: list[Any] = []

    def source(config: Any) -> Source:
        layouts.append(load_layout(config.source.dbc_path, config.source.layout))  # what the service would decode with
        return feed

    service = Service(config_path, source, notifier=ReloadNotifier(), sinks=[])
    with structlog.testing.capture_logs() as logs:
        assert service.run() == 0
    return service, service.notifier.answers, len(layouts), logs  # type: ignore[attr-defined]


def test_a_reload_with_a_damaged_models_file_is_rejected_and_the_running_models_stay(tmp_path: Path) -> None:
    # The finding: a corrupted models file was "reloaded, unchanged", and the next start failed.
    def damage(folder: Path) -> None:
        (folder / "models" / FUSED_MODEL_FILE).write_text("[full]\nfeatures = 5\n")

    service, answers, opened, logs = reload_after_editing(tmp_path, damage)
    (answer,) = answers
    assert answer.startswith("reload rejected: ") and FUSED_MODEL_FILE in answer
    assert not [e for e in logs if e["event"] == "reloaded"] and opened == 1


def test_a_valid_edit_of_the_dbc_restarts_the_source_with_it(tmp_path: Path) -> None:
    # The finding: a valid edit of the DBC was ignored until a restart ("reloaded, unchanged").
    def edit(folder: Path) -> None:
        with (folder / "bus.dbc").open("a") as f:
            f.write("\nCM_ \"edited by the keeper\";\n")

    _, answers, opened, logs = reload_after_editing(tmp_path, edit)
    assert answers == ["reloaded: the windows restart, the next is judged 6 s of data from now"]
    (reloaded,) = [e for e in logs if e["event"] == "reloaded"]
    assert reloaded["changed"] == ["source"] and opened == 2


def test_a_valid_edit_of_a_models_file_is_applied(tmp_path: Path) -> None:
    def edit(folder: Path) -> None:
        with (folder / "models" / LOAD_MODEL_FILE).open("a") as f:
            f.write("\n# refitted on the fleet\n")

    _, answers, opened, logs = reload_after_editing(tmp_path, edit)
    assert answers == ["reloaded"]
    (reloaded,) = [e for e in logs if e["event"] == "reloaded"]
    assert reloaded["changed"] == ["decision"] and opened == 1
