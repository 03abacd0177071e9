"""The recorder: the raw samples around every alarm, and periodic samples, as .csv.gz recordings for
the back office (docs/recorder.md).

It taps the monitor's blocks into a ring of the recent samples and observes its windows. A window
that raises SUSPECTED or CONFIRMED gets a SNAPSHOT: the samples from `lead_in_s` before the oldest
of the last `confirm_n` judged windows to the end of that window, so that `bogiemon replay` of the
snapshot alone, from a fresh state, goes through the same windows and raises the alarm again.
Optionally every `periodic_every_h` hours of running the next `periodic_s` seconds are written too.
No recording spans a gap: a recording is one uniformly sampled stretch.

The processing thread only copies samples; a thread of the recorder's own compresses and writes
them (a temporary '.' name, fsync, rename), then deletes the oldest recordings over the size cap.
A recording is a nicety, the events are what matter: a full queue drops the recording and a
failing disk loses it, both counted and logged, and neither ever reaches the monitor. Nor does the
disk: the recorder leaves the event store's reserve free on its file system, deleting its own
oldest files before it writes and not recording while there is no room above the reserve
(daemon/recorder_space.py: the reserve, the bound of a recording's size, the deletion).
"""

from __future__ import annotations

import math
import os
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from bogiemon.judgement.events import EventKind
from bogiemon.daemon.logs import get_logger
from bogiemon.drivers.base import Block
from bogiemon.drivers.atomic import final_name_of, write_atomically
from bogiemon.drivers.recording import RecordingFormat, write_recording
from bogiemon.daemon.recorder_space import (
    DEFAULT_RESERVE_BYTES,
    FILE_SLACK_BYTES,
    MIB,
    NAME_PATTERN,
    evict_oldest,
    own_files,
    recording_bound_bytes,
)

if TYPE_CHECKING:
    from bogiemon.judgement.verdict import WindowVerdict

# Recordings waiting for the writer at most: a default snapshot is 1.3 MiB in memory at 500 Hz.
QUEUE_RECORDINGS = 4
# The ring never takes more than this, whatever the config asks (a 1 h window confirmed over 100
# hops at 10 kHz would be gigabytes): 64 MiB is 3 h at 500 Hz. A snapshot then holds what it has.
MAX_RING_BYTES = 64 * MIB
_SAMPLE_BYTES = 3 * np.dtype(np.float32).itemsize
# How long close() waits for the writer to finish what is queued.
CLOSE_TIMEOUT_S = 30.0
REASONS = {EventKind.SUSPECTED: "suspected", EventKind.CONFIRMED: "confirmed"}
PERIODIC = "periodic"
_STAMP_FORMAT = "%Y%m%dT%H%M%SZ"
# Slack when counting whole hops between two window times (float sums of sample periods).
_HOP_SLACK = 1e-6
# While no recording comes, the writer looks this often whether the reserve is still free (the
# event store grows into it, or another program fills the disk) and gives its own files back.
SPACE_CHECK_S = 60.0

WriteRecording = Callable[[Path, NDArray[np.float64], NDArray[np.float32]], None]
# Room is made and taken by one writer at a time (during a reload, two recorders write).
_DISK_LOCK = threading.Lock()


@dataclass(frozen=True)
class RecorderSettings:
    """[recorder], and what a snapshot must span: the windows, their hop and the confirmation's n."""

    directory: Path
    lead_in_s: float = 60.0
    periodic_every_h: float = 0.0  # 0: no periodic recordings
    periodic_s: float = 300.0
    max_total_bytes: int = 512 * MIB
    format: RecordingFormat = RecordingFormat.CSV_GZ
    reserve_bytes: int = DEFAULT_RESERVE_BYTES  # free space on the folder's file system the recordings never take
    window_s: float = 120.0
    hop_s: float = 10.0
    confirm_n: int = 5
    max_block_s: float = 1.0  # the source's longest block (the tap sees a block before its windows)

    @property
    def lead_in_hops(self) -> int:
        """The lead-in in whole hops, rounded up: a replay's windows then fall where the daemon's did."""
        return max(0, math.ceil(self.lead_in_s / self.hop_s - _HOP_SLACK))

    @property
    def span_s(self) -> float:
        """The longest snapshot in seconds: the lead-in, then confirm_n windows one hop apart."""
        return self.lead_in_hops * self.hop_s + self.window_s + (self.confirm_n - 1) * self.hop_s

    @property
    def ring_s(self) -> float:
        """What the ring holds: a snapshot, and two blocks of the samples past its window."""
        return self.span_s + 2 * self.max_block_s


@dataclass
class RecorderCounters:
    snapshots_written: int = 0
    periodic_written: int = 0
    dropped: int = 0  # recordings not written because the writer was behind (the queue was full)
    no_room: int = 0  # recordings not written: they would have taken the event store's reserve
    write_errors: int = 0  # recordings lost, or files not deleted, to an OSError
    files_deleted: int = 0  # the oldest recordings, deleted to keep under max_total_bytes or the reserve free
    bytes_deleted: int = 0


@dataclass(frozen=True)
class PendingRecording:
    """One recording on its way to the disk: contiguous samples from start_s."""

    reason: str  # "suspected", "confirmed" or "periodic"
    start_s: float
    fs_hz: float
    accel_mps2: NDArray[np.float32]  # (n, 3)

    @property
    def time_s(self) -> NDArray[np.float64]:
        return self.start_s + np.arange(self.accel_mps2.shape[0]) / self.fs_hz

    def file_stem(self) -> str:
        return f"{time.strftime(_STAMP_FORMAT, time.gmtime(math.floor(self.start_s)))}_{self.reason}"


class SampleRing:
    """The latest samples of one contiguous stretch, in float32 (a 16-bit sensor's step is 5e-3
    m/s^2; float32 rounds 160 m/s^2 to 1e-5). Sample i of the stretch is at start_s + i / fs_hz,
    as the detection core times its windows."""

    def __init__(self, start_s: float, fs_hz: float, capacity_n: int) -> None:
        self.start_s = start_s
        self.fs_hz = fs_hz
        self._buffer = np.empty((capacity_n, 3), dtype=np.float32)
        self.end_index = 0  # samples of the stretch so far

    @property
    def capacity_n(self) -> int:
        return int(self._buffer.shape[0])

    @property
    def first_index(self) -> int:
        """The oldest sample of the stretch still held."""
        return max(0, self.end_index - self.capacity_n)

    def time_of(self, index: int) -> float:
        return self.start_s + index / self.fs_hz

    def index_at(self, time_s: float) -> int:
        return round((time_s - self.start_s) * self.fs_hz)

    def append(self, accel_mps2: NDArray[np.float64]) -> None:
        cap = self.capacity_n
        data = accel_mps2[-cap:]
        skipped = accel_mps2.shape[0] - data.shape[0]  # older than the ring holds
        first = (self.end_index + skipped) % cap
        head = min(data.shape[0], cap - first)
        self._buffer[first : first + head] = data[:head]
        self._buffer[: data.shape[0] - head] = data[head:]
        self.end_index += accel_mps2.shape[0]

    def take(self, start_index: int, end_index: int) -> NDArray[np.float32]:
        """A copy of samples [start_index, end_index) of the stretch, which the ring must hold."""
        assert self.first_index <= start_index <= end_index <= self.end_index
        cap = self.capacity_n
        positions = np.arange(start_index, end_index) % cap
        return self._buffer[positions]


class Recorder:
    """Taps a Monitor: `monitor.taps.append(r.on_block)`, `monitor.observers.append(r.on_window)`;
    close() at the end writes what is queued."""

    def __init__(self, settings: RecorderSettings, queue_size: int = QUEUE_RECORDINGS, write: WriteRecording | None = None) -> None:
        self.settings = settings
        self.counters = RecorderCounters()
        # The writer takes the format from the name (the temporary ends as the final name does).
        self._write_recording: WriteRecording = write or write_recording  # type: ignore[assignment]
        self._log = get_logger(component="recorder")
        self._ring: SampleRing | None = None
        self._judged_starts: deque[float] = deque(maxlen=settings.confirm_n)  # of the stretch's last judged windows
        self._running_s = 0.0  # seconds of samples fed: the clock of the periodic recordings
        period_s = settings.periodic_every_h * 3600.0
        self._next_periodic_s = period_s if period_s > 0 else math.inf
        self._periodic: list[NDArray[np.float32]] | None = None  # a periodic recording being collected
        self._periodic_start_s = 0.0
        self._periodic_left_n = 0
        self._ring_warned = False
        self._closed = False
        self._no_room_since: int | None = None  # counters.no_room when recording stopped for the reserve; None: recording
        self.ready = threading.Event()  # set once the writer has prepared the folder and given the reserve back (or failed to)
        self._unwritten = 0  # recordings queued and not yet written or lost
        self._written = threading.Condition()
        self._queue: queue.Queue[PendingRecording | None] = queue.Queue(maxsize=queue_size)
        self._writer = threading.Thread(target=self._write_loop, name="bogiemon-recorder", daemon=True)
        self._writer.start()

    # --- the processing thread: copies only -------------------------------------------------------

    def on_block(self, block: Block) -> None:
        """Keep a block's samples (the monitor's tap, called before the block's windows)."""
        ring = self._ring
        if ring is None or block.gap_before or block.fs_hz != ring.fs_hz:
            # A gap, or the stream's start or a new rate: the monitor's windows restart here, and
            # no recording reaches back across it.
            self._end_periodic()
            ring = self._ring = SampleRing(block.start_s, block.fs_hz, self._ring_capacity_n(block.fs_hz))
            self._judged_starts.clear()
        ring.append(block.accel_mps2)
        self._periodic_feed(block, ring)

    def on_window(self, report: WindowVerdict) -> None:
        """Write a snapshot for a window that raised SUSPECTED or CONFIRMED (the monitor's observer)."""
        if report.judgement is not None:
            self._judged_starts.append(report.window.start_s)
        for event in report.events:
            reason = REASONS.get(event.kind)
            if reason is not None:
                self._snapshot(reason, report.window.end_s)

    def _ring_capacity_n(self, fs_hz: float) -> int:
        wanted_n = math.ceil(self.settings.ring_s * fs_hz)
        limit_n = MAX_RING_BYTES // _SAMPLE_BYTES
        if wanted_n > limit_n and not self._ring_warned:
            self._ring_warned = True
            self._log.warning(
                "the recorder's ring is capped: snapshots hold less than the lead-in and the confirming windows",
                wanted_s=round(self.settings.ring_s, 3), held_s=round(limit_n / fs_hz, 3), fs_hz=fs_hz,
            )  # fmt: skip
        return max(2, min(wanted_n, limit_n))

    def _snapshot(self, reason: str, end_s: float) -> None:
        ring = self._ring
        if ring is None:
            return
        s = self.settings
        oldest_s = self._judged_starts[0] if self._judged_starts else end_s - s.window_s
        first_s = ring.time_of(ring.first_index)
        if oldest_s < first_s:  # the ring holds less (a recorder started on a reload): what it has
            start = ring.first_index
        else:
            # Whole hops before the oldest window, as many as the lead-in asks and the ring holds:
            # the snapshot starts on the daemon's window grid, so a replay's windows are the daemon's.
            hops = min(s.lead_in_hops, math.floor((oldest_s - first_s) / s.hop_s + _HOP_SLACK))
            start = max(ring.first_index, ring.index_at(oldest_s - hops * s.hop_s))
        end = min(ring.end_index, ring.index_at(end_s))
        if end - start >= 2:  # a recording is at least two samples
            self._submit(PendingRecording(reason, ring.time_of(start), ring.fs_hz, ring.take(start, end)))

    def _periodic_feed(self, block: Block, ring: SampleRing) -> None:
        """Collect the periodic recordings in this block's samples: one starts at the first sample
        after every periodic_every_h of running, also within the block where the last one ended (a
        block longer than the time between two recordings would otherwise delay the next ones
        until they fell a period behind and one was never written)."""
        n = block.n_samples
        before_s = self._running_s
        self._running_s += n / block.fs_hz
        at = 0  # the block's samples looked at so far
        while at < n:
            if self._periodic is not None:
                at += self._collect(block.accel_mps2[at:])
                continue
            if self._running_s < self._next_periodic_s:
                return
            offset = max(at, math.ceil((self._next_periodic_s - before_s) * block.fs_hz - _HOP_SLACK))
            if offset >= n:
                return  # the first sample after it is the next block's
            self._next_periodic_s += self.settings.periodic_every_h * 3600.0
            self._periodic = []
            self._periodic_start_s = ring.time_of(ring.end_index - n + offset)
            self._periodic_left_n = max(2, round(self.settings.periodic_s * block.fs_hz))
            at = offset

    def _collect(self, accel_mps2: NDArray[np.float64]) -> int:
        """Add samples to the periodic recording being collected, as many as it lacks; how many."""
        assert self._periodic is not None
        piece = accel_mps2[: self._periodic_left_n].astype(np.float32)
        self._periodic.append(piece)
        self._periodic_left_n -= piece.shape[0]
        if self._periodic_left_n == 0:
            self._end_periodic()
        return int(piece.shape[0])

    def _end_periodic(self) -> None:
        """Queue the periodic recording being collected (cut short at a gap or at close)."""
        pieces, self._periodic = self._periodic, None
        if pieces is None or self._ring is None:
            return
        accel = np.concatenate(pieces) if pieces else np.empty((0, 3), dtype=np.float32)
        if accel.shape[0] >= 2:
            self._submit(PendingRecording(PERIODIC, self._periodic_start_s, self._ring.fs_hz, accel))

    def _submit(self, recording: PendingRecording) -> None:
        with self._written:
            self._unwritten += 1
        try:
            self._queue.put_nowait(recording)
        except queue.Full:
            self._one_done()
            self.counters.dropped += 1
            self._log.warning(
                "recording dropped: the writer is behind", reason=recording.reason, name=recording.file_stem(),
                queued=self._queue.maxsize, dropped=self.counters.dropped,
            )  # fmt: skip

    def _one_done(self) -> None:
        with self._written:
            self._unwritten -= 1
            if self._unwritten == 0:
                self._written.notify_all()

    def wait_written(self, timeout_s: float = CLOSE_TIMEOUT_S) -> bool:
        """Wait until every recording queued so far is written, or lost; False if timeout_s passed first."""
        with self._written:
            return self._written.wait_for(lambda: self._unwritten == 0, timeout_s)

    # --- the writer thread ----------------------------------------------------------------------

    def _write_loop(self) -> None:
        if self._prepare_directory():
            self._give_back(at_start=True)
        self.ready.set()
        while True:
            try:
                recording = self._queue.get(timeout=SPACE_CHECK_S)
            except queue.Empty:
                self._give_back()
                continue
            if recording is None:
                return
            try:
                self._write(recording)
            except Exception as exc:  # noqa: BLE001 - a bug here must not end the recordings for the rest of the run
                self.counters.write_errors += 1
                self._log.error("recorder failed (a bug)", reason=recording.reason, error=repr(exc), exc_info=True)
            finally:
                self._one_done()

    def _prepare_directory(self) -> bool:
        """Create the folder; delete what a crash left half-written (only the recorder's own names)."""
        directory = self.settings.directory
        try:
            directory.mkdir(parents=True, exist_ok=True)
            with os.scandir(directory) as entries:
                stale = [
                    e.name for e in entries
                    if NAME_PATTERN.fullmatch(final_name_of(e.name) or "") and e.is_file(follow_symlinks=False)
                ]  # fmt: skip
            for name in stale:
                (directory / name).unlink(missing_ok=True)
                self._log.info("deleted a recording left half-written", path=str(directory / name))
        except OSError as exc:
            self.counters.write_errors += 1
            self._log.error("cannot prepare the recordings folder", path=str(directory), error=exc.strerror or str(exc))
            return False
        return True

    def _give_back(self, at_start: bool = False) -> None:
        """Delete the oldest recordings while the reserve is not free: at the start (an earlier run's
        recordings, a smaller disk), and while idle (the event store grew into the reserve, or another
        program filled the disk). A folder that cannot be looked at is the next recording's error."""
        directory = self.settings.directory
        with _DISK_LOCK:
            try:
                free_bytes = self._evict(directory, needed_bytes=0)
            except OSError:
                return
        if at_start:
            self._log.info("recordings folder ready", path=str(directory), free_bytes=free_bytes, reserve_bytes=self.settings.reserve_bytes)
            if free_bytes < self.settings.reserve_bytes:
                self._say_no_room(free_bytes, 0, None)

    def _write(self, recording: PendingRecording) -> None:
        directory = self.settings.directory
        path = directory / f"{recording.file_stem()}{self.settings.format.suffix}"
        with _DISK_LOCK:  # one writer on the disk: two recorders live during a reload
            try:
                directory.mkdir(parents=True, exist_ok=True)  # again: it may have been removed since
                time_s = recording.time_s
                if not self._make_room(directory, recording, time_s):
                    return
                path = self._free_name(directory, recording.file_stem())
                # Whole or not at all (drivers/atomic.py): a temporary the writer leaves on a failing
                # disk is removed there, or at the next start (_prepare_directory).
                write_atomically(path, lambda temporary: self._write_recording(temporary, time_s, recording.accel_mps2))
                size = path.stat().st_size
            except OSError as exc:
                self.counters.write_errors += 1
                self._log.error(
                    "cannot write a recording, it is lost", path=str(path), reason=recording.reason,
                    error=exc.strerror or str(exc), write_errors=self.counters.write_errors,
                )  # fmt: skip
                return
            if recording.reason == PERIODIC:
                self.counters.periodic_written += 1
            else:
                self.counters.snapshots_written += 1
            duration_s = recording.accel_mps2.shape[0] / recording.fs_hz
            self._log.info("recording written", path=str(path), reason=recording.reason, duration_s=round(duration_s, 3), bytes=size)
            if self._no_room_since is not None:
                self._log.info("recording resumed: there is room above the event store's reserve again",
                               path=str(directory), not_written=self.counters.no_room - self._no_room_since)  # fmt: skip
                self._no_room_since = None
            self._keep_under_cap(directory, keep=path.name)

    def _make_room(self, directory: Path, recording: PendingRecording, time_s: NDArray[np.float64]) -> bool:
        """Whether the recording fits above the reserve, once the oldest recordings that make room
        for it are deleted; the bound of its size is taken, the written file may only be smaller."""
        block_bytes = os.statvfs(directory).f_frsize or 4096
        bound_bytes = recording_bound_bytes(time_s, recording.accel_mps2, self.settings.format)
        needed_bytes = -(-bound_bytes // block_bytes) * block_bytes + FILE_SLACK_BYTES
        free_bytes = self._evict(directory, needed_bytes)
        if free_bytes - needed_bytes >= self.settings.reserve_bytes:
            return True
        self.counters.no_room += 1
        self._say_no_room(free_bytes, needed_bytes, recording)
        return False

    def _say_no_room(self, free_bytes: int, needed_bytes: int, recording: PendingRecording | None) -> None:
        fields = {
            "path": str(self.settings.directory), "free_bytes": free_bytes, "reserve_bytes": self.settings.reserve_bytes,
            "needed_bytes": needed_bytes, "no_room": self.counters.no_room,
            **({"reason": recording.reason, "name": recording.file_stem()} if recording is not None else {}),
        }  # fmt: skip
        if self._no_room_since is None:
            self._no_room_since = self.counters.no_room - (recording is not None)
            self._log.warning("recording stopped: no room above the event store's reserve, the events come first", **fields)
        else:
            self._log.info("recording not written: still no room above the event store's reserve", **fields)

    def _evict(self, directory: Path, needed_bytes: int) -> int:
        return evict_oldest(directory, self.settings.reserve_bytes, needed_bytes, self.counters, self._log)

    def _free_name(self, directory: Path, stem: str) -> Path:
        """<stem>.csv.gz, or <stem>-2.csv.gz, -3, ... when a recording of that second exists."""
        suffix = self.settings.format.suffix
        name, n = f"{stem}{suffix}", 1
        while (directory / name).exists():
            n += 1
            name = f"{stem}-{n}{suffix}"
        return directory / name

    def _keep_under_cap(self, directory: Path, keep: str) -> None:
        """Delete the oldest of the recorder's own files, never `keep` (just written), until the
        total is at most max_total_bytes."""
        try:
            files = own_files(directory)
        except OSError as exc:
            self.counters.write_errors += 1
            self._log.error("cannot list the recordings folder to keep it under its cap", path=str(directory), error=exc.strerror or str(exc))
            return
        total = sum(size for _, size, _ in files)
        for name, size, _ in files:
            if total <= self.settings.max_total_bytes:
                break
            if name == keep:
                continue
            try:
                (directory / name).unlink()
            except FileNotFoundError:
                pass  # an uploader took it meanwhile
            except OSError as exc:
                self.counters.write_errors += 1
                self._log.error("cannot delete an old recording", path=str(directory / name), error=exc.strerror or str(exc))
                continue
            else:
                self.counters.files_deleted += 1
                self.counters.bytes_deleted += size
            total -= size

    # --- the end ----------------------------------------------------------------------------------

    def close(self, timeout_s: float = CLOSE_TIMEOUT_S) -> None:
        """Queue what a periodic recording holds, write everything queued, stop the writer; log the counters."""
        if self._closed:
            return
        self._closed = True
        self._end_periodic()
        try:
            self._queue.put(None, timeout=timeout_s)
            self._writer.join(timeout_s)
        except queue.Full:
            pass
        if self._writer.is_alive():
            self._log.error("the recorder's writer did not finish in time: the recordings still queued are lost", timeout_s=timeout_s)
        self._log.info("recorder stopped", **vars(self.counters))




def keep_the_reserve_free(settings: RecorderSettings) -> None:
    """Delete the oldest recordings while the event store's reserve is not free, now, in this
    thread: for the service before it opens the event store, which a disk filled to its last pages
    (by an earlier version's recordings, say) does not even let open. A running recorder does the
    same from its own thread."""
    try:
        evict_oldest(settings.directory, settings.reserve_bytes, 0, RecorderCounters(), get_logger(component="recorder"))
    except OSError:
        pass  # no folder yet, or one that cannot be read: the recorder's writer says what is wrong

