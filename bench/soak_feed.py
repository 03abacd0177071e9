"""The soak's data and source: the timeline simulated in a child process, and the SoakSource
that feeds it to the daemon with the schedule's gaps, restarts and reloads applied.
"""

from __future__ import annotations

import math
import os
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parent))

from soak_schedule import FS_HZ, HOUR_S, T0_S, Action, Phase, Schedule  # noqa: E402

from bogiemon.daemon.config import load_config  # noqa: E402
from bogiemon.judgement.decision import Level  # noqa: E402
from bogiemon.judgement.verdict import WindowVerdict  # noqa: E402
from bogiemon.drivers.atomic import write_text_atomically  # noqa: E402
from bogiemon.daemon.notify import Notifier  # noqa: E402
from bogiemon.drivers.base import Block, EndOfStream, HealthCounters, SensorStatus, Source  # noqa: E402

CHUNK_S = 1800.0  # one simulated scenario
PIECE_S = 300.0  # what the generator sends at a time
BLOCK_S = 1.0  # what the source delivers at a time, as a live source would
NOISE_MPS2 = 0.01  # sensor noise, so that a standing wagon's channels are not exactly constant
FAULT = "type_a:rear_outer:0.0@leading-left"
WAIT_LIMIT_S = 120.0  # the longest the source waits for the daemon (a hung daemon fails the soak)
CALIBRATION_SEEDS = tuple(range(9000, 9012))  # 12 x 30 min of the healthy wagon
# Per-window rates for calibrate's rule: the soak judges ~8 000 windows a day, and the healthy
# ones must not confirm an alarm (the rule then also keeps 1.1 x the largest calibration deviation).
CALIBRATION_WARNING_RATE = 1e-3
CALIBRATION_ALARM_RATE = 1e-6


class SoakError(RuntimeError):
    """The soak's harness could not go on (the daemon stopped answering, the generator died)."""


# ---- the data, simulated in a child process ------------------------------------------------


@dataclass(frozen=True)
class Piece:
    """Consecutive samples of the timeline, all of one phase."""

    start_index: int  # sample index from the soak's start
    accel_mps2: NDArray[np.float64]
    status: tuple[SensorStatus, SensorStatus, SensorStatus]


def _scenario(phase: Phase, duration_s: float, seed: int) -> Any:
    from bogiemon.simulator import Scenario, SensorModel, SpeedProfile, parse_fault

    speed_kmh = 0.0 if phase.kind == "standstill" else 80.0
    faults = (parse_fault(FAULT),) if phase.kind == "fault" else ()
    return Scenario(load="full", speed=SpeedProfile.constant(speed_kmh), track="erri-low", duration_s=duration_s,
                    seed=seed, faults=faults, fs_hz=FS_HZ, sensor=SensorModel(noise_mps2=NOISE_MPS2))  # fmt: skip


def _sensor_damage(phase: Phase, accel: NDArray[np.float64]) -> tuple[SensorStatus, SensorStatus, SensorStatus]:
    """Apply a stuck or dead channel in place; the status bits the sensors report with it."""
    status = [SensorStatus.OK] * 3
    if phase.kind == "stuck" and phase.channel is not None:
        accel[:, phase.channel] = accel[0, phase.channel]  # the converter repeats its last value
    elif phase.kind == "dead" and phase.channel is not None:
        accel[:, phase.channel] = 0.0  # no supply: reads zero and says so
        status[phase.channel] = SensorStatus.SENSOR_FAULT
    return (status[0], status[1], status[2])


def generate(schedule: Schedule, out: Any, base_seed: int) -> None:
    """The child process: simulate the timeline chunk by chunk and send it in pieces, then None."""
    from bogiemon.simulator import simulate

    seed = base_seed
    piece_n = int(PIECE_S * FS_HZ)
    for phase in schedule.phases:
        start_n, end_n = int(round(phase.start_s * FS_HZ)), int(round(phase.end_s * FS_HZ))
        for chunk_start in range(start_n, end_n, int(CHUNK_S * FS_HZ)):
            chunk_n = min(int(CHUNK_S * FS_HZ), end_n - chunk_start)
            accel = simulate(_scenario(phase, chunk_n / FS_HZ, seed)).accel_mps2
            seed += 1
            status = _sensor_damage(phase, accel)
            for lo in range(0, chunk_n, piece_n):
                out.put(Piece(chunk_start + lo, np.ascontiguousarray(accel[lo : lo + piece_n]), status))
            del accel
    out.put(None)


def calibration_fragment(config_path: str) -> tuple[str, str]:
    """The child process: thresholds learned on a healthy run of the same wagon; (fragment, summary)."""
    from bogiemon.daemon.calibrate import calibrate_windows, fragment
    from bogiemon.detection import IndicatorStream
    from bogiemon.simulator import simulate

    config = load_config(config_path)
    stream = IndicatorStream(config.processing_settings(FS_HZ), config.bogie_geometry(), 0.0, config.health.clip_level_mps2)
    windows = []
    healthy = Phase("healthy", 0.0, CHUNK_S)
    for seed in CALIBRATION_SEEDS:  # consecutive runs, as the soak feeds them: no gap between
        windows += stream.process(simulate(_scenario(healthy, CHUNK_S, seed)).accel_mps2)
    result = calibrate_windows(windows, config, "full", warning_rate=CALIBRATION_WARNING_RATE, alarm_rate=CALIBRATION_ALARM_RATE)
    summary = "; ".join(
        f"{c.name} center {c.threshold.center:+.4g} warning {c.threshold.warning:.4g} alarm {c.threshold.alarm:.4g}"
        for c in result.indicators
    )
    return fragment(result), f"{result.n_judged} of {result.n_windows} calibration windows judged: {summary}"


# ---- the source and what the harness sees of the daemon -----------------------------------


class Observer:
    """The daemon's window reports, counted; the end of the latest window, for the source's waits."""

    def __init__(self) -> None:
        self.windows = 0
        self.last_end_s = -math.inf
        # (window end, the trend below its warning level) of every judged window with a trend:
        # when the fused decision may clear after a repair.
        self.trend_below_warning: list[tuple[float, bool]] = []
        self._cond = threading.Condition()

    def observe(self, report: WindowVerdict) -> None:
        with self._cond:
            self.windows += 1
            self.last_end_s = report.window.end_s
            j = report.judgement
            if j is not None and math.isfinite(j.trend):
                self.trend_below_warning.append((report.window.end_s - T0_S, j.trend_level < Level.WARNING))
            self._cond.notify_all()

    def wait_for_window_end(self, end_s: float, timeout_s: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self.last_end_s >= end_s - 0.5 / FS_HZ, timeout_s)


class RecordingNotifier(Notifier):
    """The service's sd_notify calls, kept (no systemd here): how the harness sees a reload end."""

    def __init__(self) -> None:
        super().__init__(environ={})
        self.statuses: list[str] = []
        self._cond = threading.Condition()

    def notify(self, **fields: object) -> bool:
        with self._cond:
            if "ready" in fields:
                self.statuses.append(str(fields.get("status", "")))
                self._cond.notify_all()
        return True

    def wait_for_status(self, prefix: str, seen: int, timeout_s: float) -> bool:
        """Wait for a READY status starting with prefix after the first `seen` ones."""
        with self._cond:
            return self._cond.wait_for(lambda: any(s.startswith(prefix) for s in self.statuses[seen:]), timeout_s)


@dataclass
class Lifetime:
    """One run of the service, as the feed saw it."""

    blocks: int = 0
    samples: int = 0
    gap_blocks: int = 0  # blocks after the first with gap_before
    segment_lengths: list[int] = field(default_factory=list)  # samples per monitor segment
    reloads: int = 0
    bad_reloads: int = 0
    exit_status: int | None = None


@dataclass
class Feed:
    """The data timeline across services: pieces from the generator, cut into blocks, the actions applied."""

    schedule: Schedule
    pieces: Any  # the generator's queue
    hop_n: int
    hops_per_window: int
    position: int = 0  # next sample index to deliver
    actions: list[Action] = field(default_factory=list)
    fed_samples: int = 0
    lost_samples: int = 0
    rss_samples: list[tuple[float, float, int]] = field(default_factory=list)  # (hours of data, RSS MB, epoch)
    epoch: int = 0  # counts restarts and applied reloads: each starts a new pipeline or core
    config_hashes: list[tuple[float, str]] = field(default_factory=list)  # (data time from, hash)
    variant: str = "a"  # the config file's variant in force ("a" or "b": they differ in wagon.id)
    _piece: Piece | None = None
    _done: bool = False

    def __post_init__(self) -> None:
        self.actions = list(self.schedule.actions)

    @property
    def exhausted(self) -> bool:
        return self._done

    def next_variant(self) -> str:
        return "b" if self.variant == "a" else "a"

    def current_piece(self) -> Piece | None:
        """The piece holding `position`, fetching the next from the generator as needed."""
        while self._piece is None or self.position >= self._piece.start_index + self._piece.accel_mps2.shape[0]:
            if self._piece is not None:
                self._piece = None  # dropped before the next arrives: RSS is sampled with none held
                self.rss_samples.append((self.position / FS_HZ / HOUR_S, rss_mb(), self.epoch))
            try:
                piece = self.pieces.get(timeout=WAIT_LIMIT_S)
            except queue.Empty:
                raise SoakError(f"the data generator sent nothing for {WAIT_LIMIT_S:g} s") from None
            if piece is None:
                self._done = True
                return None
            self._piece = piece
        return self._piece

    def skip(self, seconds: float) -> None:
        """Lose the next `seconds` of data (a dropout, or the daemon being down)."""
        end = self.position + int(round(seconds * FS_HZ))
        while self.position < end and self.current_piece() is not None:
            assert self._piece is not None
            piece_end = self._piece.start_index + self._piece.accel_mps2.shape[0]
            step = min(end, piece_end) - self.position
            self.position += step
            self.lost_samples += step

    def take(self, max_n: int, stop_index: int | None) -> Block | None:
        piece = self.current_piece()
        if piece is None:
            return None
        lo = self.position - piece.start_index
        hi = min(lo + max_n, piece.accel_mps2.shape[0])
        if stop_index is not None:
            hi = min(hi, stop_index - piece.start_index)
        block = Block(start_s=T0_S + self.position / FS_HZ, fs_hz=FS_HZ, accel_mps2=piece.accel_mps2[lo:hi].copy(), status=piece.status)
        self.position += hi - lo
        self.fed_samples += hi - lo
        return block


class SoakSource(Source):
    """One service's source: the feed's blocks, the restarts and gaps applied, reloads driven.

    finite: the pipeline waits for the core instead of dropping (replay as fast as it goes).
    A reload happens at a hop boundary of the current segment, once the window ending there has
    been judged, so it falls between two known samples and the windows can be counted exactly.
    """

    finite = True

    def __init__(self, feed: Feed, config_path: Path, variants: dict[str, str], observer: Observer, notifier: RecordingNotifier) -> None:
        self.fs_hz = FS_HZ
        self.counters = HealthCounters()
        self.feed = feed
        self.config_path = config_path
        self.variants = variants
        self.observer = observer
        self.notifier = notifier
        self.lifetime = Lifetime()
        self._block_n = int(BLOCK_S * FS_HZ)
        self._segment_start: int | None = None  # sample index of the current segment's first sample
        self._segment_n = 0
        self._gap_next = False
        self._ended = False
        self._reload_at: int | None = None  # the snapped sample index of a pending reload
        self._reload_sent: tuple[int, float] | None = None  # READY statuses seen when SIGHUP went, wall time
        self._waiting_since: float | None = None

    def read(self, timeout_s: float) -> Block | None:
        if self._ended:
            raise EndOfStream
        action = self.feed.actions[0] if self.feed.actions else None
        if action is not None and self._reload_at is None and self.feed.position >= int(round(action.at_s * FS_HZ)):
            if action.kind == "restart":
                self.feed.actions.pop(0)
                self.feed.skip(action.lost_s)
                return self._end()
            if action.kind == "gap":
                self.feed.actions.pop(0)
                self.feed.skip(action.lost_s)
                self._close_segment()
                self._gap_next = True
            else:
                self._reload_at = self._next_hop_boundary()
        if self._reload_at is not None and self.feed.position >= self._reload_at:
            return self._drive_reload(timeout_s)
        block = self.feed.take(self._block_n, self._reload_at)
        if block is None:
            return self._end()
        if self._gap_next or self.lifetime.blocks == 0:
            block = Block(block.start_s, block.fs_hz, block.accel_mps2, gap_before=True, status=block.status)
            if self.lifetime.blocks:
                self.lifetime.gap_blocks += 1
                self.counters.gaps += 1
            self._gap_next = False
        if self._segment_start is None:
            self._segment_start = self.feed.position - block.n_samples
        self._segment_n += block.n_samples
        self.lifetime.blocks += 1
        self.lifetime.samples += block.n_samples
        self.counters.frames += block.n_samples
        return block

    def _end(self) -> Block | None:
        self._close_segment()
        self._ended = True
        raise EndOfStream

    def _close_segment(self) -> None:
        """What follows starts a new segment of the monitor (a gap, a reload, the end)."""
        if self._segment_n:
            self.lifetime.segment_lengths.append(self._segment_n)
        self._segment_start, self._segment_n = None, 0

    def _next_hop_boundary(self) -> int:
        """The first hop boundary from now on whose window lies inside the current segment."""
        start = self.feed.position if self._segment_start is None else self._segment_start
        hops = max(self.feed.hops_per_window, math.ceil((self.feed.position - start) / self.feed.hop_n))
        return start + hops * self.feed.hop_n

    def _waited_too_long(self, what: str) -> None:
        now = time.monotonic()
        self._waiting_since = self._waiting_since or now
        if now - self._waiting_since > WAIT_LIMIT_S:
            raise SoakError(f"{what}: nothing for {WAIT_LIMIT_S:g} s")

    def _drive_reload(self, timeout_s: float) -> Block | None:
        action = self.feed.actions[0]
        assert self._reload_at is not None
        if self._reload_sent is None:
            if not self.observer.wait_for_window_end(T0_S + self._reload_at / FS_HZ, timeout_s):
                self._waited_too_long("the window before a reload was never judged")
                return None  # the core is still on the last blocks: come back
            variant = "bad" if action.kind == "bad-reload" else self.feed.next_variant()
            write_text_atomically(self.config_path, self.variants[variant])
            self._reload_sent, self._waiting_since = (len(self.notifier.statuses), time.monotonic()), None
            os.kill(os.getpid(), signal.SIGHUP)
            return None
        prefix = "reload rejected" if action.kind == "bad-reload" else "reloaded"
        if not self.notifier.wait_for_status(prefix, self._reload_sent[0], timeout_s):
            self._waited_too_long(f"no '{prefix}' from the service after SIGHUP")
            return None
        self.feed.actions.pop(0)
        self._reload_at = self._reload_sent = self._waiting_since = None
        if action.kind == "bad-reload":
            self.lifetime.bad_reloads += 1
            write_text_atomically(self.config_path, self.variants[self.feed.variant])  # a restart must read a valid file
        else:
            self.lifetime.reloads += 1
            self.feed.variant = self.feed.next_variant()
            self.feed.epoch += 1
            self.feed.config_hashes.append((self.feed.position / FS_HZ, load_config(self.config_path).digest()))
            self._close_segment()  # the monitor restarts its windows on a reload
        return None




def rss_mb() -> float:
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20
