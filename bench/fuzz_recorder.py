"""Fuzz target of the recorder under a full disk: the recorder beside the event store on a real small
tmpfs (docs/recorder.md, "The reserve"), the disk filled to seeded random levels around the event
store's reserve, with seeded random alarm sequences.

Each input lays out the disk afresh: the state folder and the recordings folder on one file
system of 48 MiB (a tmpfs mounted by the worker in a mount namespace of its own, so that it goes
with the worker however the worker ends), recordings of an earlier run and files that are not the
recorder's (one a symlink named like a recording), and another program's file filling the disk to
a level drawn around the reserve (below it down to what the store needs for the input, at it,
a snapshot's room above it, far above it). The config is the daemon tests' short windows with a
[recorder] in CSV or Parquet, a lead-in, periodic recordings or not, a cap from 1 MiB up, and MQTT
status messages or not (19.6 or 29.4 MiB of reserve). Then, as `bogiemon run` does: the reserve
given back before the store opens, the event store, a Monitor holding what the store refuses (the
service's), the Recorder on its taps; blocks of healthy running and of a broken spring (pitch
coupled to roll, tests/daemon/synthetic.py) in a random order, between blocks the other program's
file growing into the reserve or shrinking, and an uploader taking the oldest recording. Each
block's recordings are written before the next block comes, so that the free space measured
after a write is what the recorder left.

Wrong results: a commit the store refused, an event unlike those of the same blocks without the
recorder (a MemoryEventLog), free space below the reserve after a recording was written, a write
attempt that left the reserve unfree while the recorder still held files, recordings that do not
add up (written + no room + dropped + write errors = the snapshots of the SUSPECTED and CONFIRMED
events and the periodic recordings the running time asks for; a write error at all; the files left
= the earlier ones + written - deleted - uploaded; the bytes deleted = the sizes of the files gone),
and a written recording that does not read back. Where mounting is not allowed the target is not
run and says why.
"""

from __future__ import annotations

import ctypes
import errno
import math
import os
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import structlog

import fuzz_core

from bogiemon.daemon.config import BogiemonConfig, parse_config
from bogiemon.judgement.events import Event, EventKind
from bogiemon.daemon.monitor import MemoryEventLog, Monitor
from bogiemon.daemon.recorder import Recorder, RecorderSettings
from bogiemon.daemon.recorder_space import NAME_PATTERN
from bogiemon.daemon.statedir import give_back
from bogiemon.daemon.store import EventStore
from bogiemon.drivers.atomic import final_name_of
from bogiemon.drivers.base import Block
from bogiemon.drivers.recording import RecordingError, open_recording_reader, write_recording
from tests.daemon.synthetic import FS_HZ, as_blocks, bogie_accel, short_windows_config

MIB = 1 << 20
DISK_SIZE = "48m"  # the reserve with MQTT status messages (29.4 MiB), earlier recordings and room above
# The least free space an input leaves the event store by other programs' files: what it takes
# for one start and a few dozen commits (its WAL grows 30 kB a commit from a start, its -shm is
# 32 KiB; docs/recorder.md). Below it a refused commit would be the other program's doing.
STORE_ROOM_BYTES = 3 * MIB
GOLDEN = (math.sqrt(5) - 1) / 2  # a periodic recording's period is a whole number of samples and this much:
# its k-th start never falls within a few hundredths of a sample of a sample's time (k < 20)
START_S = 1.7e9


# ---- a tmpfs of the worker's own -----------------------------------------------------------------

CLONE_NEWNS = 0x00020000
MS_REC = 0x4000
MS_PRIVATE = 1 << 18


def _libc() -> Any:
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mount.argtypes = (ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_ulong, ctypes.c_char_p)
    libc.unshare.argtypes = (ctypes.c_int,)
    return libc


_DISK: dict[str, Path | str] = {}


def unavailable(name: str) -> str | None:
    """None once this worker has its tmpfs (mounted in a mount namespace of its own), else why not."""
    if "disk" in _DISK:
        return None
    if "why" in _DISK:
        return str(_DISK["why"])
    why = _mount()
    if why is not None:
        _DISK["why"] = why
    return why


def _mount() -> str | None:
    if os.geteuid() != 0:
        return "mounting a small tmpfs needs root"
    libc = _libc()
    # The mounts of this process only: the tmpfs goes with the worker, however it ends.
    if libc.unshare(CLONE_NEWNS) != 0:
        return f"cannot have a mount namespace of its own: {os.strerror(ctypes.get_errno())}"
    if libc.mount(b"none", b"/", None, MS_REC | MS_PRIVATE, None) != 0:
        return f"cannot make its mounts private: {os.strerror(ctypes.get_errno())}"
    root = fuzz_core.scratch_root(f"bogiemon-fuzz-{os.getpid()}-disk-")
    if libc.mount(b"tmpfs", str(root).encode(), b"tmpfs", 0, f"size={DISK_SIZE},mode=0755".encode()) != 0:
        code = ctypes.get_errno()
        return f"cannot mount a tmpfs here: {os.strerror(code)}" + (" (no CAP_SYS_ADMIN?)" if code == errno.EPERM else "")
    _DISK["disk"] = root
    return None


def _disk() -> Path:
    if unavailable("recorder-disk") is not None:
        raise RuntimeError(f"no tmpfs: {_DISK.get('why')}")  # the harness asks unavailable() before any input
    disk = _DISK["disk"]
    assert isinstance(disk, Path)
    return disk


def free_bytes(path: Path) -> int:
    usage = os.statvfs(path)
    return usage.f_bavail * usage.f_frsize


# ---- an input ---------------------------------------------------------------------------------


def generate(rng: random.Random) -> fuzz_core.Input:
    segments: list[list[Any]] = []
    for _ in range(rng.randint(1, 5)):
        segments.append([rng.choice(("healthy", "broken")), rng.choice((6, 8, 12, 20, 30)) + rng.randint(0, 8)])
    if all(kind == "healthy" for kind, _ in segments):
        segments.insert(rng.randrange(len(segments) + 1), ["broken", rng.choice((12, 20))])
    n_blocks_guess = sum(s for _, s in segments) * FS_HZ / 50
    periodic = rng.random() < 0.5
    period_n = rng.randint(300, 1500) + GOLDEN
    level = rng.choice(("below", "below", "at", "edge", "edge", "above", "far", "empty"))
    return {
        "seed": rng.randrange(2**31),
        "segments": segments,
        "block_n": rng.choice((25, 50, 50, 100, 200)),
        "format": rng.choice(("csv.gz", "parquet")),
        "mqtt_status": rng.random() < 0.3,
        "in_state_dir": rng.random() < 0.5,
        "lead_in_s": rng.choice((0.0, 2.0, 3.0, 10.0)),
        "clear_after_windows": rng.choice((2, 3, 5)),
        "periodic_every_h": period_n / FS_HZ / 3600 if periodic else 0.0,
        "periodic_s": round(rng.uniform(0.5, 0.8 * period_n / FS_HZ), 2) if periodic else 300.0,
        "max_total_bytes": rng.choice((MIB, 2 * MIB, 8 * MIB, 512 * MIB)),
        "earlier": [rng.choice((2_000, 60_000, 400_000, 1_500_000)) for _ in range(rng.choice((0, 0, 1, 3, 8)))],
        "foreign": rng.random() < 0.3,
        # Free space once filled, from the reserve: below it (down to the store's room), at it, a
        # recording's room above it, far above; or no filler at all.
        "level": level,
        "level_bytes": {"below": -rng.randint(0, 20) * MIB - rng.randint(0, MIB), "at": rng.randint(-8192, 8192),
                        "edge": rng.randint(0, 600_000), "above": rng.randint(1, 6) * MIB, "far": 0, "empty": 0}[level],  # fmt: skip
        # Between blocks: another program's file grows or shrinks, an uploader takes the oldest recording.
        "disk_events": [[rng.randrange(max(1, int(n_blocks_guess))), rng.choice(("grow", "grow", "shrink", "upload")),
                         rng.choice((64 * 1024, 512 * 1024, 3 * MIB, 40 * MIB))] for _ in range(rng.choice((0, 1, 3, 8)))],  # fmt: skip
    }


def config_text(data: fuzz_core.Input, state: Path, recordings: Path) -> str:
    text = short_windows_config(data["clear_after_windows"], state_dir=state)
    text += (
        f'[recorder]\nenabled = true\ndirectory = "{recordings}"\nlead_in_s = {data["lead_in_s"]!r}\n'
        f'periodic_every_h = {data["periodic_every_h"]!r}\nperiodic_s = {data["periodic_s"]!r}\n'
        f'max_total_bytes = {data["max_total_bytes"]}\nformat = "{data["format"]}"\n'
    )
    if data["mqtt_status"]:
        text += '[wagon]\nid = "w1"\n[mqtt]\nenabled = true\n'
    return text


def signal_of(data: fuzz_core.Input) -> np.ndarray:
    seed = data["seed"]
    parts = [bogie_accel(duration_s, seed + i, pitch_roll_coupling=1.0 if kind == "broken" else 0.0)
             for i, (kind, duration_s) in enumerate(data["segments"])]  # fmt: skip
    accel = np.vstack(parts)
    if data["periodic_every_h"] > 0:  # the end never within two samples of a periodic recording's start
        period_n = data["periodic_every_h"] * 3600 * FS_HZ
        while any(-1.0 < accel.shape[0] - k * period_n < 3.0 for k in range(1, int(accel.shape[0] / period_n) + 2)):
            accel = np.vstack([accel, accel[-7:]])
    return accel


def expected_periodic(n_samples: int, settings: RecorderSettings) -> int:
    """The periodic recordings n samples ask for: one starting at the first sample after every
    periodic_every_h of running, written if it holds two samples or more by the end (the reference)."""
    if settings.periodic_every_h <= 0:
        return 0
    period_n = settings.periodic_every_h * 3600 * FS_HZ
    count, k = 0, 1
    while k * period_n <= n_samples:
        if n_samples - math.ceil(k * period_n) >= 2:
            count += 1
        k += 1
    return count


def _fill(filler: Path, disk: Path, free_wanted: int) -> None:
    """Grow or shrink another program's file until free_wanted bytes (to the page) are free."""
    size = filler.stat().st_size if filler.exists() else 0
    change = free_bytes(disk) - free_wanted
    new_size = max(0, size + change)
    with filler.open("ab") as f:
        if new_size < size:
            f.truncate(new_size)
        else:
            left = new_size - size
            while left > 0:
                f.write(bytes(min(left, MIB)))
                left -= min(left, MIB)


@dataclass
class Files:
    """The recorder's own files as the harness saw them: sizes of every one ever written or kept."""

    sizes: dict[str, int]
    earlier: int
    uploaded: set[str] = field(default_factory=set)  # taken by the uploader, not the recorder


def own_files(folder: Path) -> dict[str, int]:
    """The recorder's files (its names, regular files, no symlinks) and their sizes."""
    out: dict[str, int] = {}
    try:
        entries = list(os.scandir(folder))
    except FileNotFoundError:
        return out
    for entry in entries:
        if NAME_PATTERN.fullmatch(entry.name) and entry.is_file(follow_symlinks=False):
            out[entry.name] = entry.stat(follow_symlinks=False).st_size
    return out


def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    with structlog.testing.capture_logs():  # the recorder's log lines, kept out of the report
        return _run(data, ctx)


def _run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    disk = _disk()
    for entry in disk.iterdir():
        fuzz_core.remove_tree(entry)
    state = disk / "state"
    recordings = state / "recordings" if data["in_state_dir"] else disk / "recordings"
    recordings.mkdir(parents=True)
    config = parse_config(config_text(data, state, recordings), "fuzz")
    settings = config.recorder_settings()
    assert settings is not None
    reserve = settings.reserve_bytes
    rng = np.random.default_rng(data["seed"])
    for day, size in enumerate(data["earlier"], start=1):
        (recordings / f"2020{(day - 1) // 28 + 1:02d}{(day - 1) % 28 + 1:02d}T000000Z_periodic{settings.format.suffix}").write_bytes(rng.bytes(size))
    filler = disk / "filler"
    filler.touch()
    if data["foreign"]:
        (recordings / "notes.txt").write_bytes(bytes(50_000))
        (recordings / "20190101T000000Z_confirmed.csv.gz").symlink_to(filler)
    if data["level"] not in ("far", "empty"):
        _fill(filler, disk, max(STORE_ROOM_BYTES, reserve + data["level_bytes"]))
    elif data["level"] == "far":
        _fill(filler, disk, free_bytes(disk) - 4 * MIB)

    written: list[tuple[str, int, int]] = []  # (final name, size, free bytes with it on the disk)

    def write(path: Path, time_s: np.ndarray, accel_mps2: np.ndarray) -> None:
        write_recording(path, time_s, accel_mps2, fsync=True)
        written.append((final_name_of(path.name) or path.name, path.stat().st_size, free_bytes(disk)))

    blocks = as_blocks(signal_of(data), start_s=START_S, block_n=data["block_n"])
    # As `bogiemon run` starts: the reserve given back, then the store, the monitor, the recorder.
    give_back(config)
    verdict = _gave_back(disk, recordings, reserve, "before the store opens")
    if verdict is not None:
        return verdict
    # The recorder's counters start here: what the start deleted is no recording of this run's.
    files = Files(own_files(recordings), earlier=len(own_files(recordings)))
    store = EventStore(state)
    recorder = Recorder(settings, write=write)
    try:
        monitor = Monitor(config.monitor_settings(), store, observers=[recorder.on_window], taps=[recorder.on_block], hold_uncommitted=True)
        if not recorder.ready.wait(30):
            return "the recorder's writer never got ready"
        verdict = _gave_back(disk, recordings, reserve, "at the recorder's start")
        if verdict is not None:
            return verdict
        events: list[Event] = []
        events_at: dict[Any, list[Any]] = {}
        for e in data["disk_events"]:
            events_at.setdefault(e[0], []).append(e)
        attempts = 0
        for i, block in enumerate(blocks):
            events += monitor.feed(block)
            if not recorder.wait_written(30):
                return f"the recorder's writer did not finish block {i}'s recordings in 30 s"
            c = recorder.counters
            now = c.snapshots_written + c.periodic_written + c.no_room + c.dropped + c.write_errors
            if now != attempts:
                attempts = now
                verdict = _gave_back(disk, recordings, reserve, f"after a recording of block {i}")
                if verdict is not None:
                    return verdict
            for _, what, n_bytes in events_at.get(i, []):
                _disk_event(what, n_bytes, disk, filler, recordings, files)
        for name, size in own_files(recordings).items():
            files.sizes.setdefault(name, size)
    finally:
        recorder.close()
        store.close()
    for name, size, _ in written:
        files.sizes[name] = size
    return _judge(data, config, blocks, events, monitor, recorder, written, files, recordings, reserve, state)


def _disk_event(what: str, n_bytes: int, disk: Path, filler: Path, recordings: Path, files: Files) -> None:
    if what == "grow":  # another program, or the store, takes room: never what the store itself needs
        _fill(filler, disk, max(STORE_ROOM_BYTES, free_bytes(disk) - n_bytes))
    elif what == "shrink":
        _fill(filler, disk, free_bytes(disk) + min(n_bytes, filler.stat().st_size))
    else:
        own = sorted(own_files(recordings).items())
        if own:
            name, size = own[0]
            files.sizes.setdefault(name, size)
            (recordings / name).unlink()
            files.uploaded.add(name)


def _gave_back(disk: Path, recordings: Path, reserve: int, when: str) -> fuzz_core.Verdict:
    """After the recorder looked at the disk: the reserve free, or none of its files left to give."""
    free = free_bytes(disk)
    own = own_files(recordings)
    if free < reserve and own:
        return f"the reserve not given back {when}: {free} bytes free of the {reserve} reserved, {len(own)} recordings kept ({sum(own.values())} bytes)"
    return None


def _judge(data: fuzz_core.Input, config: BogiemonConfig, blocks: list[Block], events: list[Event], monitor: Monitor,
           recorder: Recorder, written: list[tuple[str, int, int]], files: Files, recordings: Path, reserve: int,
           state: Path) -> fuzz_core.Verdict:  # fmt: skip
    if monitor.store_failures or monitor.held:
        return f"a commit refused: {monitor.store_failures} refused commits, {len(monitor.held)} events held ({monitor.store_failure})"
    stored = EventStore(state, readonly=True)
    try:
        in_store = stored.events()
    finally:
        stored.close()
    if [e.event_id for e in in_store] != [e.event_id for e in events]:
        return f"events lost to the store: {len(events)} committed, {len(in_store)} stored"
    reference = _without_recorder(config, blocks)
    if [(e.kind, e.time_s) for e in events] != reference:
        return f"events unlike those without the recorder: {[(e.kind.value, e.time_s) for e in events][:6]} against {reference[:6]}"
    low = [(name, free) for name, _, free in written if free < reserve]
    if low:
        return f"the reserve taken: {low[0][1]} bytes free with {low[0][0]} written, {reserve} reserved"
    c = recorder.counters
    snapshots = sum(1 for e in events if e.kind in (EventKind.SUSPECTED, EventKind.CONFIRMED))
    assert recorder.settings is not None
    periodic = expected_periodic(sum(b.n_samples for b in blocks), recorder.settings)
    outcomes = c.snapshots_written + c.periodic_written + c.no_room + c.dropped + c.write_errors
    if outcomes != snapshots + periodic:
        return f"counters do not add up: {vars(c)} for {snapshots} snapshots and {periodic} periodic recordings"
    if c.write_errors:
        return f"a write error on a disk the recorder had made room on: {vars(c)}"
    if len(written) != c.snapshots_written + c.periodic_written:
        return f"counters do not add up: {len(written)} recordings written, counted {c.snapshots_written} + {c.periodic_written}"
    left = own_files(recordings)
    if len(left) != files.earlier + len(written) - c.files_deleted - len(files.uploaded):
        return (f"counters do not add up: {len(left)} recordings left, {files.earlier} earlier + {len(written)} written - "
                f"{c.files_deleted} deleted - {len(files.uploaded)} uploaded")  # fmt: skip
    gone = set(files.sizes) - set(left) - files.uploaded
    if c.bytes_deleted != sum(files.sizes[name] for name in gone):
        return f"counters do not add up: {c.bytes_deleted} bytes deleted, the files gone held {sum(files.sizes[n] for n in gone)}"
    for name, _, _ in written:
        if name in left:
            try:
                open_recording_reader(recordings / name)
            except RecordingError as exc:
                return f"a recording written does not read back: {exc}"
    return None


def _without_recorder(config: BogiemonConfig, blocks: list[Block]) -> list[tuple[EventKind, float]]:
    monitor = Monitor(config.monitor_settings(), MemoryEventLog())
    return [(e.kind, e.time_s) for block in blocks for e in monitor.feed(block)]


TARGETS = [fuzz_core.Target("recorder-disk", generate, run)]
