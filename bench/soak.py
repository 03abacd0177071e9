"""Soak test: the daemon fed 24 simulated hours of 500 Hz data, faster than real time, on a schedule.

The real Service (its pipeline threads, ring, monitor, SQLite event store, log sink, SIGHUP
reload) runs in this process's main thread, fed by a source that replays simulated runs of one
wagon (full load, 80 km/h, ERRI low-level track) as fast as the daemon takes them. A child
process simulates the data chunk by chunk (30 min scenarios, sent in 5 min pieces), so memory
stays bounded and this process never imports the simulator. On a schedule: a broken rear outer
coil at the leading-left corner for 30 to 60 min, then healthy again (three times); a channel
stuck, a dead channel with its sensor-fault bit, an hour of frequent dropouts, a standstill;
gaps; config reloads by SIGHUP (one rejected); restarts of the service on the same state dir,
one during an alarm and one during a sensor fault.

The decision is the daemon's default, decision.method "fused" with its trend, with the load
fixed at "full", on the wagon's own calibration, learned by bogiemon.daemon.calibrate from a
healthy calibration run of the same simulated wagon (2 h, other seeds), written beside the
config and included (the fragment holds the fused baseline and the thresholds alike).

It checks: RSS flat (the least-squares slope after the first WARMUP_H simulated hours below
RSS_SLOPE_BOUND_MB_PER_H, with a level of its own after each in-process restart or reload: see
rss_slope_mb_per_h), no exception escapes (every service exits 0, no error in the log
but the rejected reload), every expected event exactly once in the event store (one CONFIRMED
per fault phase and one CLEARED of it after the phase, none elsewhere; SENSOR_FAULT events only
in sensor phases, one SENSOR_CLEARED after each), events carry the config hash in force, and
the counters add up (per service: judged + gated + sensor-fault windows = windows = what the
segments fed allow, samples and blocks = those fed, nothing dropped by the ring).
Exit status 0 when every check passes, 1 otherwise; figures printed and written as JSON.
Run with `make soak` or `.venv/bin/python bench/soak.py [--short] [--json PATH]`.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import queue
import signal
import sys
import tempfile
import threading
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.daemon.config import BogiemonConfig, load_config
from bogiemon.daemon.decision import Level
from bogiemon.daemon.events import Event, EventKind
from bogiemon.daemon.logs import configure_logging
from bogiemon.daemon.monitor import WindowReport
from bogiemon.daemon.notify import Notifier
from bogiemon.daemon.service import Service
from bogiemon.daemon.store import EventStore
from bogiemon.drivers.base import Block, EndOfStream, HealthCounters, SensorStatus, Source

FS_HZ = 500.0
T0_S = 1.8e9  # data time of the first sample, Unix seconds
HOUR_S = 3600.0
CHUNK_S = 1800.0  # one simulated scenario
PIECE_S = 300.0  # what the generator sends at a time
BLOCK_S = 1.0  # what the source delivers at a time, as a live source would
NOISE_MPS2 = 0.01  # sensor noise, so that a standing wagon's channels are not exactly constant
FAULT = "type_a:rear_outer:0.0@leading-left"
WARMUP_H = 2.0
RSS_SLOPE_BOUND_MB_PER_H = 1.0
WAIT_LIMIT_S = 120.0  # the longest the source waits for the daemon (a hung daemon fails the soak)
CALIBRATION_SEEDS = tuple(range(9000, 9012))  # 12 x 30 min of the healthy wagon
# Per-window rates for calibrate's rule: the soak judges ~8 000 windows a day, and the healthy
# ones must not confirm an alarm (the rule then also keeps 1.1 x the largest calibration deviation).
CALIBRATION_WARNING_RATE = 1e-3
CALIBRATION_ALARM_RATE = 1e-6
RESULTS = Path(__file__).resolve().parent / "results" / "soak-latest.json"


class SoakError(RuntimeError):
    """The soak's harness could not go on (the daemon stopped answering, the generator died)."""


# ---- the schedule -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Phase:
    """A stretch of the data timeline: healthy, a suspension fault, a sensor fault, a standstill."""

    kind: str  # "healthy", "fault", "stuck", "dead", "dropouts", "standstill"
    start_s: float  # data time from the soak's start
    duration_s: float
    channel: int | None = None  # stuck/dead: the channel (0..2)

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    @property
    def is_sensor_phase(self) -> bool:
        return self.kind in ("stuck", "dead", "dropouts")

    def label(self) -> str:
        where = f" a{self.channel + 1}" if self.channel is not None else ""
        return f"{self.kind}{where} {self.start_s / HOUR_S:05.2f}-{self.end_s / HOUR_S:05.2f} h"


@dataclass(frozen=True)
class Action:
    """Something done to the daemon or its data at a data time."""

    at_s: float
    kind: str  # "gap" (samples lost), "restart", "reload", "bad-reload"
    lost_s: float = 0.0  # gap and restart: seconds of data that never reach the daemon


@dataclass(frozen=True)
class Schedule:
    phases: tuple[Phase, ...]
    actions: tuple[Action, ...]

    @property
    def duration_s(self) -> float:
        return self.phases[-1].end_s


def _phases(spec: list[tuple[str, float, int | None]]) -> tuple[Phase, ...]:
    out, t = [], 0.0
    for kind, hours, channel in spec:
        out.append(Phase(kind, t, hours * HOUR_S, channel))
        t += hours * HOUR_S
    return tuple(out)


def _dropout_gaps(phase: Phase, every_s: float = 300.0, lost_s: float = 2.0) -> list[Action]:
    """Frequent dropouts: a short loss every 5 min, 12 an hour, above health.max_gaps_per_hour."""
    return [Action(phase.start_s + k * every_s, "gap", lost_s) for k in range(1, int(phase.duration_s // every_s) + 1)]


def day_schedule() -> Schedule:
    """24 simulated hours; hours of the actions are data time from the start."""
    phases = _phases([
        ("healthy", 2.0, None), ("fault", 0.75, None), ("healthy", 2.25, None), ("stuck", 0.5, 1),
        ("healthy", 1.5, None), ("standstill", 1 / 3, None), ("healthy", 5 / 3, None), ("fault", 1.0, None),
        ("healthy", 2.0, None), ("dropouts", 1.0, None), ("healthy", 2.0, None), ("dead", 0.5, 2),
        ("healthy", 2.5, None), ("fault", 0.5, None), ("healthy", 5.5, None),
    ])  # fmt: skip
    h = HOUR_S
    actions = [
        Action(1.0 * h, "gap", 3.0), Action(2.5 * h, "restart", 5.0), Action(3.5 * h, "reload"),
        Action(6.0 * h, "restart", 5.0), Action(8.0 * h, "gap", 10.0), Action(9.5 * h, "reload"),
        Action(11.0 * h, "bad-reload"), Action(15.25 * h, "restart", 5.0), Action(16.0 * h, "reload"),
        Action(20.0 * h, "restart", 5.0), Action(22.0 * h, "gap", 60.0),
    ]  # fmt: skip
    dropouts = next(p for p in phases if p.kind == "dropouts")
    return Schedule(phases, tuple(sorted(actions + _dropout_gaps(dropouts), key=lambda a: a.at_s)))


def short_schedule() -> Schedule:
    """About 6 simulated hours with one of everything: for trying the soak out, not for its figures."""
    phases = _phases([
        ("healthy", 0.75, None), ("fault", 0.5, None), ("healthy", 0.5, None), ("stuck", 0.25, 1),
        ("healthy", 0.25, None), ("standstill", 0.25, None), ("healthy", 0.25, None), ("dropouts", 1.0, None),
        ("healthy", 1.25, None), ("dead", 0.25, 2), ("healthy", 0.5, None),
    ])  # fmt: skip
    h = HOUR_S
    actions = [
        Action(0.5 * h, "gap", 3.0), Action(1.0 * h, "restart", 5.0), Action(1.5 * h, "reload"),
        Action(2.05 * h, "bad-reload"), Action(5.1 * h, "restart", 5.0), Action(5.5 * h, "reload"),
    ]  # fmt: skip
    dropouts = next(p for p in phases if p.kind == "dropouts")
    return Schedule(phases, tuple(sorted(actions + _dropout_gaps(dropouts), key=lambda a: a.at_s)))


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

    def observe(self, report: WindowReport) -> None:
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
            write_atomically(self.config_path, self.variants[variant])
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
            write_atomically(self.config_path, self.variants[self.feed.variant])  # a restart must read a valid file
        else:
            self.lifetime.reloads += 1
            self.feed.variant = self.feed.next_variant()
            self.feed.epoch += 1
            self.feed.config_hashes.append((self.feed.position / FS_HZ, load_config(self.config_path).digest()))
            self._close_segment()  # the monitor restarts its windows on a reload
        return None


def write_atomically(path: Path, text: str) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def rss_mb() -> float:
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


# ---- running it -------------------------------------------------------------------------------


def config_text(state_dir: Path, wagon_id: str) -> str:
    # The daemon's default decision (fused, with its trend) on the wagon's own calibration,
    # the load fixed (the simulated wagon runs loaded all day).
    return "\n".join([
        'include = ["thresholds.toml"]',
        "[wagon]", f'id = "{wagon_id}"',
        "[processing]", f"fs_hz = {FS_HZ}",
        "[decision]", 'method = "fused"', 'load = "full"',
        "[state]", f'directory = "{state_dir}"', "",
    ])  # fmt: skip


def bad_config_text(good: str) -> str:
    return good.replace('load = "full"', 'load = "full"\nconfirm_k = 9\nconfirm_n = 5')


@dataclass
class SoakRun:
    schedule: Schedule
    calibration: str
    lifetimes: list[Lifetime]
    feed: Feed
    observer_windows: int
    wall_s: float
    events: list[Event]
    log_records: list[dict[str, Any]]
    final_state: dict[str, Any]
    escaped: list[str]  # exceptions that ended a thread
    trend_below_warning: list[tuple[float, bool]]  # Observer's, data time from the first sample


def run_soak(schedule: Schedule, workdir: Path) -> SoakRun:
    state_dir = workdir / "state"
    config_path = workdir / "bogiemon.toml"
    variants = {"a": config_text(state_dir, "soak-a"), "b": config_text(state_dir, "soak-b")}
    variants["bad"] = bad_config_text(variants["a"])
    (workdir / "thresholds.toml").write_text("")
    write_atomically(config_path, variants["a"])
    ctx = multiprocessing.get_context("spawn")
    pieces = ctx.Queue(maxsize=4)
    generator = ctx.Process(target=generate, args=(schedule, pieces, 1), name="soak-generator", daemon=True)
    generator.start()
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        fragment_text, calibration = pool.submit(calibration_fragment, str(config_path)).result()
    (workdir / "thresholds.toml").write_text(fragment_text)
    config = load_config(config_path)
    settings = config.processing_settings(FS_HZ)
    feed = Feed(schedule, pieces, settings.hop_n, settings.window_n // settings.hop_n)
    feed.config_hashes.append((0.0, config.digest()))
    observer = Observer()
    log_path = workdir / "daemon.log"
    lifetimes: list[Lifetime] = []
    escaped: list[str] = []  # exceptions that ended a thread: the pipeline's own catch them and log
    threading.excepthook = lambda args: escaped.append(f"{args.thread.name if args.thread else '?'}: {args.exc_type.__name__}: {args.exc_value}")
    t0 = time.monotonic()
    with log_path.open("w") as log:
        configure_logging(stream=log)
        while not feed.exhausted:
            notifier = RecordingNotifier()
            source = SoakSource(feed, config_path, variants, observer, notifier)
            service = Service(config_path, lambda _c, s=source: s, notifier=notifier, observers=[observer.observe])
            service.install_signal_handlers()
            source.lifetime.exit_status = service.run()
            lifetimes.append(source.lifetime)
            feed.epoch += 1
            if source.lifetime.exit_status != 0:
                break
    wall_s = time.monotonic() - t0
    threading.excepthook = threading.__excepthook__
    if not feed.exhausted:
        generator.terminate()  # a service failed: the checks say which
    generator.join(timeout=30)
    store = EventStore(state_dir, readonly=True)
    try:
        events, final_state = store.events(), store.get_state("monitor") or {}
    finally:
        store.close()
    records = [json.loads(line.split(">", 1)[1]) for line in log_path.read_text().splitlines() if line.startswith("<")]
    return SoakRun(schedule, calibration, lifetimes, feed, observer.windows, wall_s, events, records, final_state, escaped, observer.trend_below_warning)


# ---- the checks -------------------------------------------------------------------------------


@dataclass
class Checks:
    passed: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)

    def expect(self, ok: bool, what: str) -> None:
        (self.passed if ok else self.failed).append(what)


def data_s(event: Event) -> float:
    return event.time_s - T0_S


def check_events(run: SoakRun, window_s: float, hop_s: float, clear_after: int, sensor_clear_after: int, checks: Checks) -> None:
    events = run.events
    confirmed = [e for e in events if e.kind is EventKind.CONFIRMED]
    cleared_alarms = [e for e in events if e.kind is EventKind.CLEARED and e.details.get("cleared") == "confirmed"]
    faults = [p for p in run.schedule.phases if p.kind == "fault"]
    # A CONFIRMED needs confirm_k windows at alarm; a CLEARED clear_after windows below warning,
    # the first window wholly after the fault ending window_s after it, and with the fused
    # decision its trend below its own warning level too (it decays over the trend's time
    # constant after the repair).
    confirm_by_s = window_s + 6 * hop_s
    for p in faults:
        mine = [e for e in confirmed if p.start_s <= data_s(e) <= p.start_s + confirm_by_s]
        checks.expect(len(mine) == 1, f"{p.label()}: one CONFIRMED within {confirm_by_s:g} s of the onset (got {len(mine)})")
        clear_by_s = 2 * window_s + (clear_after + 3) * hop_s
        trend_ok = next((t for t, ok in run.trend_below_warning if t >= p.end_s + window_s and ok), None)
        if run.trend_below_warning and trend_ok is not None:
            clear_by_s = max(clear_by_s, trend_ok - p.end_s + (clear_after + 3) * hop_s)
        cleared = [e for e in cleared_alarms if p.end_s <= data_s(e) <= p.end_s + clear_by_s]
        checks.expect(len(cleared) == 1, f"{p.label()}: one CLEARED of it within {clear_by_s:g} s of the repair (got {len(cleared)})")
    checks.expect(len(confirmed) == len(faults), f"CONFIRMED only in fault phases: {len(confirmed)} for {len(faults)} faults")
    checks.expect(len(cleared_alarms) == len(faults), f"alarms CLEARED once each: {len(cleared_alarms)} for {len(faults)} faults")
    sensor_faults = [e for e in events if e.kind is EventKind.SENSOR_FAULT]
    sensor_cleared = [e for e in events if e.kind is EventKind.SENSOR_CLEARED]
    sensor_phases = [p for p in run.schedule.phases if p.is_sensor_phase]

    def owner(e: Event) -> Phase | None:
        """The latest sensor phase begun by the event's window end, if the event is in its reach."""
        begun = [p for p in sensor_phases if p.start_s <= data_s(e)]
        return begun[-1] if begun and data_s(e) <= begun[-1].end_s + settle_s(begun[-1]) else None

    def settle_s(p: Phase) -> float:
        # Dropouts are judged over the last hour: they clear an hour after the last one.
        return (HOUR_S if p.kind == "dropouts" else 0.0) + window_s + (sensor_clear_after + 2) * hop_s

    for p in sensor_phases:
        mine = [e for e in sensor_faults if owner(e) is p]
        sets = [json.dumps(e.details.get("problems"), sort_keys=True) for e in mine]
        # The daemon raises a SENSOR_FAULT only when a problem not yet reported appears: every
        # event of the phase must name a (channel, problem) pair that no earlier one did.
        seen: set[tuple[str, str]] = set()
        stale = 0
        for e in mine:
            pairs = {(ch, what) for ch, whats in (e.details.get("problems") or {}).items() for what in whats}
            stale += not (pairs - seen)
            seen |= pairs
        checks.expect(bool(mine) and stale == 0 and all(data_s(e) <= p.end_s + window_s for e in mine),
                      f"{p.label()}: SENSOR_FAULT raised within it, once per new problem ({len(mine)}: {', '.join(sets)})")  # fmt: skip
        clear = [e for e in sensor_cleared if owner(e) is p]
        checks.expect(len(clear) == 1 and data_s(clear[0]) >= p.end_s if clear else False,
                      f"{p.label()}: one SENSOR_CLEARED after it, within {settle_s(p):g} s (got {len(clear)})")  # fmt: skip
    strays = [e for e in sensor_faults + sensor_cleared if owner(e) is None]
    checks.expect(not strays, f"sensor events only in sensor phases ({len(strays)} outside: {[round(data_s(e)) for e in strays][:5]})")
    ids = [e.event_id for e in events]
    checks.expect(len(set(ids)) == len(ids), "no event stored twice")
    times = [e.time_s for e in events]
    checks.expect(times == sorted(times), "events stored in time order")
    def hash_in_force(t_s: float) -> str:
        return [h for since_s, h in run.feed.config_hashes if since_s <= t_s + 0.5 / FS_HZ][-1]

    # A window never spans a reload (the windows restart there): its events carry the hash in
    # force at its start.
    wrong = [e for e in events if e.config_hash != hash_in_force(data_s(e) - window_s)]
    checks.expect(not wrong, f"every event carries the config hash in force for its window ({len(wrong)} do not)")
    mode = run.final_state.get("decision", {}).get("mode")
    reported = run.final_state.get("health", {}).get("reported")
    checks.expect(mode == "normal" and reported == {}, f"the day ends normal with healthy sensors (mode {mode}, sensors {reported})")


def stopped_records(run: SoakRun) -> list[dict[str, Any]]:
    return [r for r in run.log_records if r.get("event") == "stopped"]


def check_counters(run: SoakRun, hop_n: int, hops_per_window: int, checks: Checks) -> dict[str, int]:
    stops = stopped_records(run)
    checks.expect(len(stops) == len(run.lifetimes), f"every service logged its counters when it stopped ({len(stops)} of {len(run.lifetimes)})")
    totals: Counter[str] = Counter()
    for i, (life, stop) in enumerate(zip(run.lifetimes, stops, strict=False)):
        c, src, ring = stop["counters"], stop["source"], stop["ring"]
        totals.update({k: v for k, v in c.items() if isinstance(v, int)})
        expected_windows = sum(max(0, n // hop_n - hops_per_window + 1) for n in life.segment_lengths)
        expected_segments = 1 + life.gap_blocks + life.reloads
        both = c["judged"] + c["gated"] + c["sensor_fault_windows"]
        problems = []
        if c["windows"] != expected_windows:
            problems.append(f"windows {c['windows']} != {expected_windows} the segments allow")
        if both != c["windows"]:
            problems.append(f"judged {c['judged']} + gated {c['gated']} + sensor-fault {c['sensor_fault_windows']} != windows {c['windows']}")
        if (c["samples"], c["blocks"]) != (life.samples, life.blocks):
            problems.append(f"samples/blocks {c['samples']}/{c['blocks']} != fed {life.samples}/{life.blocks}")
        if c["segments"] != expected_segments:
            problems.append(f"segments {c['segments']} != 1 + {life.gap_blocks} gaps + {life.reloads} reloads")
        if (src["frames"], src["gaps"]) != (life.samples, life.gap_blocks):
            problems.append(f"source frames/gaps {src['frames']}/{src['gaps']} != {life.samples}/{life.gap_blocks}")
        if not (ring["blocks_in"] == ring["blocks_out"] == life.blocks and ring["samples_dropped"] == ring["overflows"] == 0):
            problems.append(f"ring {ring} != {life.blocks} blocks in and out, none dropped")
        checks.expect(not problems, f"service {i + 1}: counters add up" + (": " + "; ".join(problems) if problems else ""))
    checks.expect(totals["windows"] == run.observer_windows, f"window reports {run.observer_windows} = windows counted {totals['windows']}")
    checks.expect(totals["events"] == len(run.events), f"events counted {totals['events']} = events stored {len(run.events)}")
    checks.expect(sum(life.samples for life in run.lifetimes) == run.feed.fed_samples, "every sample fed reached a service")
    return dict(totals)


def check_health(run: SoakRun, checks: Checks) -> tuple[float, float]:
    statuses = [life.exit_status for life in run.lifetimes]
    checks.expect(all(s == 0 for s in statuses), f"every service exited 0 ({statuses})")
    checks.expect(not run.escaped, f"no exception ended a thread ({run.escaped[:3]})")
    errors = [r for r in run.log_records if r.get("level") == "error"]
    rejected = [r for r in errors if r.get("event", "").startswith("reload rejected")]
    bad = sum(life.bad_reloads for life in run.lifetimes)
    checks.expect(len(rejected) == bad and len(errors) == len(rejected),
                  f"no error in the log but the {bad} rejected reload(s): {[r.get('event') for r in errors if r not in rejected][:3]}")  # fmt: skip
    restarts = len(run.lifetimes) - 1
    planned = sum(1 for a in run.schedule.actions if a.kind == "restart")
    checks.expect(restarts == planned and run.feed.exhausted, f"the whole timeline was fed, {restarts} of {planned} restarts")
    slope = rss_slope_mb_per_h(run.feed.rss_samples)
    checks.expect(abs(slope) < RSS_SLOPE_BOUND_MB_PER_H,
                  f"RSS flat after {WARMUP_H:g} h: slope {slope:+.3f} MB per simulated hour (bound {RSS_SLOPE_BOUND_MB_PER_H:g})")  # fmt: skip
    return slope, max(mb for _, mb, _ in run.feed.rss_samples)


def rss_slope_mb_per_h(samples: list[tuple[float, float, int]]) -> float:
    """Least-squares RSS slope after the warm-up, one intercept per epoch.

    A restart in this process starts new threads, which glibc may give new malloc arenas: RSS
    steps once (bounded: the arenas are reused) where a real restart would start a new process;
    a reload rebuilds the core. Those steps are not growth, so each epoch has its own level.
    """
    warm = [(h, mb, e) for h, mb, e in samples if h >= WARMUP_H]
    epochs = sorted({e for _, _, e in warm})
    if len(warm) < len(epochs) + 2:
        return math.nan
    design = np.zeros((len(warm), 1 + len(epochs)))
    for row, (h, _, e) in enumerate(warm):
        design[row, 0], design[row, 1 + epochs.index(e)] = h, 1.0
    coef, *_ = np.linalg.lstsq(design, np.array([mb for _, mb, _ in warm]), rcond=None)
    return float(coef[0])


def rss_steps_mb(samples: list[tuple[float, float, int]]) -> list[float]:
    """RSS change across each restart or reload: the first sample of an epoch minus the last before it."""
    return [round(b[1] - a[1], 2) for a, b in zip(samples, samples[1:], strict=False) if b[2] != a[2]]


# ---- the report -------------------------------------------------------------------------------


def summary(run: SoakRun, checks: Checks, slope: float, peak_mb: float, totals: dict[str, int]) -> dict[str, Any]:
    fed_h = run.feed.fed_samples / FS_HZ / HOUR_S
    rss = run.feed.rss_samples
    warm = [mb for h, mb, _ in rss if h >= WARMUP_H]
    cleared = Counter(str(e.details.get("cleared")) for e in run.events if e.kind is EventKind.CLEARED)
    return {
        "simulated_hours": run.schedule.duration_s / HOUR_S,
        "fed_hours": fed_h,
        "lost_s": run.feed.lost_samples / FS_HZ,
        "wall_s": run.wall_s,
        "x_real_time": fed_h * HOUR_S / run.wall_s,
        "rss_mb": {"first": rss[0][1], "after_warmup": warm[0] if warm else None, "end": rss[-1][1], "max": peak_mb,
                   "slope_mb_per_h": slope, "bound_mb_per_h": RSS_SLOPE_BOUND_MB_PER_H, "samples": len(rss),
                   "steps_at_restarts_and_reloads": rss_steps_mb(rss),
                   "by_hour": [[round(h, 3), round(mb, 2), e] for h, mb, e in rss]},
        "events": dict(Counter(e.kind.value for e in run.events)),
        "cleared": dict(cleared),
        "counters": totals,
        "services": len(run.lifetimes),
        "reloads": sum(life.reloads for life in run.lifetimes),
        "rejected_reloads": sum(life.bad_reloads for life in run.lifetimes),
        "gaps": sum(life.gap_blocks for life in run.lifetimes),
        "calibration": run.calibration,
        "checks_passed": len(checks.passed),
        "checks_failed": checks.failed,
        "passed": not checks.failed,
    }  # fmt: skip


def print_report(s: dict[str, Any], checks: Checks, run: SoakRun) -> None:
    rss, c = s["rss_mb"], s["counters"]
    print(f"soak: {s['simulated_hours']:.2f} simulated hours ({s['fed_hours']:.3f} h fed, {s['lost_s']:.0f} s lost to gaps and restarts)"
          f" in {s['wall_s']:.0f} s wall: {s['x_real_time']:.0f}x real time")
    print(f"calibration: {s['calibration']}")
    print(f"RSS: {rss['first']:.1f} MB at the first piece, {rss['after_warmup']:.1f} MB after {WARMUP_H:g} h, {rss['end']:.1f} MB at the end,"
          f" max {rss['max']:.1f} MB; slope {rss['slope_mb_per_h']:+.3f} MB per simulated hour (bound {rss['bound_mb_per_h']:g});"
          f" steps at in-process restarts and reloads {rss['steps_at_restarts_and_reloads']} MB")
    print("events: " + ", ".join(f"{k} {v}" for k, v in sorted(s["events"].items()))
          + " (CLEARED of " + ", ".join(f"{k} {v}" for k, v in sorted(s["cleared"].items())) + ")")
    print(f"counters: windows {c['windows']} = judged {c['judged']} + gated {c['gated']} + sensor-fault {c['sensor_fault_windows']};"
          f" samples {c['samples']} = fed {run.feed.fed_samples}; blocks {c['blocks']}; segments {c['segments']}; events {c['events']}")
    print(f"services: {s['services']} ({s['services'] - 1} restarts), reloads {s['reloads']} applied + {s['rejected_reloads']} rejected, {s['gaps']} gaps")
    for phase in run.schedule.phases:
        if phase.kind != "healthy":
            got = Counter(e.kind.value for e in run.events if phase.start_s <= data_s(e) < phase.end_s + 600.0)
            print(f"  {phase.label():<26} events within it (+10 min): " + (", ".join(f"{k} {v}" for k, v in sorted(got.items())) or "none"))
    for what in checks.failed:
        print(f"FAILED: {what}")
    print(f"checks: {len(checks.passed)} passed, {len(checks.failed)} failed: {'PASS' if s['passed'] else 'FAIL'}")  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--short", action="store_true", help="about 6 simulated hours with one of everything (trying it out)")
    parser.add_argument("--json", type=Path, default=RESULTS, help="where to write the figures (default bench/results/soak-latest.json)")
    parser.add_argument("--keep", type=Path, help="keep the state directory, config and daemon log in this folder")
    args = parser.parse_args()
    schedule = short_schedule() if args.short else day_schedule()
    with tempfile.TemporaryDirectory(prefix="bogiemon-soak-") as tmp:
        workdir = args.keep or Path(tmp)
        workdir.mkdir(parents=True, exist_ok=True)
        try:
            run = run_soak(schedule, workdir)
        except SoakError as exc:
            print(f"soak: error: {exc}", file=sys.stderr)
            return 2
        config: BogiemonConfig = load_config(workdir / "bogiemon.toml")
        settings = config.processing_settings(FS_HZ)
        checks = Checks()
        slope, peak_mb = check_health(run, checks)
        totals = check_counters(run, settings.hop_n, settings.window_n // settings.hop_n, checks)
        check_events(run, settings.window_s, settings.hop_s, config.decision.clear_after_windows, config.health.clear_after_windows, checks)
    s = summary(run, checks, slope, peak_mb, totals)
    print_report(s, checks, run)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({**s, "schedule": [asdict(p) for p in schedule.phases], "checks": checks.passed}, indent=2) + "\n")
    return 0 if s["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
