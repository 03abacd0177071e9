"""Fuzz target of reloads: the service (daemon/service.py, in this process) over a healthy bogie and
then a broken spring (pitch coupled to roll, tests/daemon/synthetic.py), under seeded random
sequences of real SIGHUPs between blocks.

Each reload first rewrites the config file: the same text; another decision setting; other windows
(window_s, hop_s: the windows restart); another ring size (the source restarts: a new stream); or a
config the service must reject (bad TOML, a bad value, an include that is no list, the file gone,
a folder, a FIFO, a file past the config's size cap). Some reloads are storms of up to 12 SIGHUPs,
each sent once the service's handler took the one before. The feed holds the next block until the
monitor has taken every block before it and the service has done every reload the SIGHUPs asked
for (its requests count them), so that each reload lands between two known blocks.

Wrong results: an exit status other than 0; events or windows other than those of a Monitor fed the
same blocks and reconfigured at the same blocks (MemoryEventLog: the reference); a reload rejected
that should apply or applied that should be rejected; a windows restart said (log, STATUS) where the
windows did not restart, or not said where they did; windows other than those the stretches between
restarts hold, counted independently (every window judged, none lost to a reload); no CONFIRMED when
the broken spring ran long enough after the last restart; a thread or a file descriptor left behind.
"""

from __future__ import annotations

import os
import random
import signal
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import structlog

import fuzz_core
from bogiemon.daemon.config import parse_config
from bogiemon.daemon.monitor import MemoryEventLog, Monitor, MonitorSettings, windows_of
from bogiemon.daemon.notify import Notifier
from bogiemon.daemon.pipeline import Pipeline
from bogiemon.daemon.service import Service
from bogiemon.daemon.signals import Requests
from bogiemon.daemon.sinks import MemorySink
from bogiemon.drivers.base import Block, EndOfStream
from tests.daemon.synthetic import FS_HZ, as_blocks, bogie_accel, short_windows_config
from tests.daemon.test_service import FeedSource

# The service checks its reload flag every tick: half the watchdog interval (daemon/service.py).
WATCHDOG_USEC = 100_000
ANSWER_S = 30.0  # a reload (or storm) done within this, at the latest (a loaded machine)
# Broken running after the last restart of the windows that must give a CONFIRMED: a window (8 s at
# most), confirm_k = 2 of confirm_n = 3 at a hop of 3 s at most, and margin.
CONFIRM_WITHIN_S = 40.0
WINDOWS = ((6.0, 2.0), (6.0, 3.0), (8.0, 2.0), (8.0, 4.0))  # (window_s, hop_s): a window is whole hops
GOOD = ("same", "decision", "windows", "source")
BAD = ("toml", "value", "include", "missing", "folder", "fifo", "huge")


def generate(rng: random.Random) -> fuzz_core.Input:
    healthy_s, broken_s = rng.choice((10, 20, 40)), rng.choice((30, 50, 80))
    n_blocks = int((healthy_s + broken_s) * FS_HZ) // 50
    n_reloads = rng.choice((1, 3, 8, 20, 40))
    at = sorted({rng.randrange(1, n_blocks) for _ in range(n_reloads)})
    reloads = []
    for block in at:
        kind = rng.choices((*GOOD, *BAD), weights=(8, 4, 2, 1, *(1,) * len(BAD)))[0]
        reloads.append({
            "block": block, "kind": kind,
            "storm": rng.choice((1, 1, 1, 2, 5, 12)),
            "clear_after_windows": rng.randint(2, 9),
            **dict(zip(("window_s", "hop_s"), rng.choice(WINDOWS), strict=True)),
            "ring_capacity_s": rng.choice((30.0, 60.0, 90.0)),
        })  # fmt: skip
    return {"seed": rng.randrange(2**31), "healthy_s": healthy_s, "broken_s": broken_s, "reloads": reloads}


@dataclass(frozen=True)
class Settings:
    """What the harness writes into the config: the parts a reload may change."""

    clear_after_windows: int = 3
    window_s: float = 6.0
    hop_s: float = 2.0
    ring_capacity_s: float = 60.0

    def text(self, state: Path) -> str:
        base = short_windows_config(self.clear_after_windows, state_dir=state)
        base = base.replace("window_s = 6.0", f"window_s = {self.window_s!r}").replace("hop_s = 2.0", f"hop_s = {self.hop_s!r}")
        return base + f"[pipeline]\nring_capacity_s = {self.ring_capacity_s!r}\n"


def _bad_file(kind: str, path: Path, good_text: str) -> None:
    """The config file as a reload must reject it (the service keeps its running config)."""
    _remove(path)
    if kind == "toml":
        path.write_text(good_text + "[[[ not toml\n")
    elif kind == "value":
        path.write_text(good_text.replace("hop_s = ", "hop_s = -", 1))
    elif kind == "include":
        path.write_text("include = 5\n" + good_text)
    elif kind == "folder":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "huge":
        path.write_text(good_text + "#" * (4 << 20) + "\n")
    # "missing": no file at all


def _remove(path: Path) -> None:
    """The config file, or what a bad reload left in its place (a folder, a FIFO: never opened)."""
    if path.is_dir() and not path.is_symlink():
        fuzz_core.remove_tree(path)
    elif os.path.lexists(path):
        path.unlink()


@dataclass
class Plan:
    """The reloads as the harness expects them to go: per block, the settings applied there."""

    applied: dict[int, tuple[Settings, bool]] = field(default_factory=dict)  # block -> (settings, source restarted)
    restarts_said: list[bool] = field(default_factory=list)  # per reload that applied a change
    rejected: int = 0


class ReloadFeed:
    """The blocks, one reload (or storm) before each block the input names; shared by every source
    the service opens, so that a source opened again goes on where the last one stopped."""

    def __init__(self, blocks: list[Block], data: fuzz_core.Input, config: Path, state: Path) -> None:
        self.blocks, self.config, self.state = blocks, config, state
        self.broken_s = float(data["broken_s"])
        self.reloads = {r["block"]: r for r in data["reloads"]}
        self.current = Settings()
        self.plan = Plan()
        self.service: TappedService | None = None
        self.next = 0
        self.taken = 0  # blocks the monitor has taken (its tap)
        self.sending: dict | None = None  # the reload being sent before block `next`
        self.sent = 0  # its SIGHUPs sent so far
        self.failure: str | None = None

    def tap(self, _block: Block) -> None:
        self.taken += 1

    def read(self, timeout_s: float) -> Block | None:
        if self.next >= len(self.blocks) or self.failure is not None:
            raise EndOfStream
        reload = self.reloads.get(self.next)
        if reload is not None:
            if self.sending is None:
                if self.taken < self.next:  # the monitor has not taken every block before this one yet
                    time.sleep(0.002)
                    return None
                self._write(reload)
                self.sending, self.sent, self._deadline = reload, 0, time.monotonic() + ANSWER_S
            # Done within this read's time, else None: a source restarted by the reload must let
            # its thread go (the service joins it) while the reload is still on.
            if not self._storm(timeout_s):
                return None
            self.sending = None
            self.reloads.pop(self.next)
        self.next += 1
        return self.blocks[self.next - 1]

    def _write(self, reload: dict) -> None:
        """The config file as this reload has it, and what the service should make of it."""
        new = Settings(**{k: reload[k] for k in ("clear_after_windows", "window_s", "hop_s", "ring_capacity_s")})
        kind, now = reload["kind"], self.current
        if kind in BAD:
            _bad_file(kind, self.config, now.text(self.state))
            self.plan.rejected += 1
            return
        new = {"same": now, "decision": replace(now, clear_after_windows=new.clear_after_windows),
               "windows": replace(now, window_s=new.window_s, hop_s=new.hop_s),
               "source": replace(now, ring_capacity_s=new.ring_capacity_s)}[kind]  # fmt: skip
        _remove(self.config)
        self.config.write_text(new.text(self.state))
        if new != now:
            source = new.ring_capacity_s != now.ring_capacity_s
            self.plan.applied[self.next] = (new, source)
            self.plan.restarts_said.append(source or (new.window_s, new.hop_s) != (now.window_s, now.hop_s))
        self.current = new

    def _storm(self, timeout_s: float) -> bool:
        """Send the reload's SIGHUPs one after the other, each once the service's handler has taken
        the one before (signals that wait coalesce), then wait for every reload they asked for."""
        service = self.service
        assert service is not None and self.sending is not None
        until = min(time.monotonic() + timeout_s, self._deadline)
        while time.monotonic() < until:
            if service.hups == service.hups_before + self.sent:
                if self.sent < self.sending["storm"]:
                    self.sent += 1
                    os.kill(os.getpid(), signal.SIGHUP)
                    continue
                if service.idle():
                    service.hups_before = service.hups
                    return True
            time.sleep(0.002)
        if time.monotonic() >= self._deadline:
            self.failure = f"the reloads before block {self.next} not done in {ANSWER_S:g} s"
            return True
        return False


class CountedRequests(Requests):
    """The service's requests, counting the reloads taken: each is counted as it is taken, so that
    no reload asked for with every taken reload done means no reload is on or to come."""

    def __init__(self) -> None:
        super().__init__()
        self.taken = 0

    def take_reload(self) -> bool:
        taken = super().take_reload()
        self.taken += taken
        return taken


class TappedService(Service):
    """The service, with the feed's tap on its monitor (how many blocks the monitor has taken), and
    counts of the SIGHUPs its handler took and the reloads it did."""

    requests: CountedRequests

    def __init__(self, *args: Any, tap: Callable[[Block], None], **kwargs: Any) -> None:
        super().__init__(*args, **{**kwargs, "requests": CountedRequests()})
        self._tap = tap
        self.hups = self.hups_before = 0
        self.reloads_done = 0

    def run(self) -> int:
        try:
            return super().run()
        finally:
            self.requests.close()  # the service leaves requests it was given open

    def install_signal_handlers(self) -> None:
        super().install_signal_handlers()
        handler = signal.getsignal(signal.SIGHUP)
        assert callable(handler)

        def counted(signum: int, frame: FrameType | None) -> None:
            handler(signum, frame)
            self.hups += 1

        signal.signal(signal.SIGHUP, counted)

    def idle(self) -> bool:
        return not self.requests.reload and self.requests.taken == self.reloads_done

    def _reload(self, pipeline: Pipeline, monitor: Monitor) -> Pipeline:
        try:
            return super()._reload(pipeline, monitor)
        finally:
            self.reloads_done += 1

    def _start_pipeline(self, monitor: Monitor) -> Pipeline:
        if self._tap not in monitor.taps:
            monitor.taps.append(self._tap)
        return super()._start_pipeline(monitor)


def _threads_and_fds() -> tuple[int, int]:
    return threading.active_count(), len(os.listdir("/proc/self/fd"))


def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    folder = ctx.fresh_dir()
    state, config = folder / "state", folder / "bogiemon.toml"
    config.write_text(Settings().text(state))
    accel = np.vstack([bogie_accel(data["healthy_s"], data["seed"]), bogie_accel(data["broken_s"], data["seed"] + 1, pitch_roll_coupling=1.0)])
    blocks = as_blocks(accel)
    before = _threads_and_fds()
    # A watchdog interval only to make the service's tick short (the notifier has no socket to send to).
    notifier = Notifier({"WATCHDOG_USEC": str(WATCHDOG_USEC)})
    saved = {signum: signal.getsignal(signum) for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)}
    try:
        feed = ReloadFeed(blocks, data, config, state)
        sink = MemorySink()
        windows: list[Any] = []
        # ReloadFeed is duck-typed to what FeedSource reads of a feed.
        service = TappedService(config, lambda _config: FeedSource(feed), notifier=notifier, sinks=[sink], observers=[windows.append], tap=feed.tap)  # type: ignore[arg-type]
        feed.service = service
        service.install_signal_handlers()
        with structlog.testing.capture_logs() as logs:
            status = service.run()
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler)
    if feed.failure is not None:
        return f"no answer: {feed.failure}"
    if status != 0:
        return f"the service exited {status}"
    if feed.next != len(blocks):
        return f"the service stopped at block {feed.next} of {len(blocks)}"
    return _judge(feed, blocks, sink, windows, logs, before)


def _judge(feed: ReloadFeed, blocks: list[Block], sink: MemorySink, windows: list[Any], logs: Sequence[Mapping[str, Any]], before: tuple[int, int]) -> fuzz_core.Verdict:
    plan = feed.plan
    rejected = [e for e in logs if e["event"].startswith("reload rejected")]
    reloaded = [e for e in logs if e["event"] == "reloaded" and not e.get("unchanged")]
    if len(rejected) < plan.rejected or len(reloaded) != len(plan.applied):
        return f"reloads: {len(reloaded)} applied and {len(rejected)} rejected, {len(plan.applied)} and {plan.rejected} sent"
    said = [bool(e["windows_restart"]) for e in reloaded]
    if said != plan.restarts_said:
        return f"a windows restart said wrongly: {said} for {plan.restarts_said}"
    # The reference: the monitor's own code, reconfigured at the same blocks; beside it, the windows
    # counted stretch by stretch (a stretch ends where the windows restart).
    reference = Monitor(_monitor_settings(Settings(), feed.state), MemoryEventLog())
    ref_events = []
    stretches: list[list] = [[0, Settings()]]  # [samples, settings]
    for i, block in enumerate(blocks):
        if i in plan.applied:
            settings, source = plan.applied[i]
            monitor_settings = _monitor_settings(settings, feed.state)
            restart = windows_of(monitor_settings) != windows_of(reference.settings)
            reference.reconfigure(monitor_settings)
            if source:
                reference.new_stream()
            if restart or source:
                stretches.append([0, settings])
            stretches[-1][1] = settings
        ref_events += reference.feed(block)
        stretches[-1][0] += block.n_samples
    got = [(e.kind.value, e.time_s) for e in sink.events]
    want = [(e.kind.value, e.time_s) for e in ref_events]
    if got != want:
        return f"events unlike the reference monitor's: {got[:6]} against {want[:6]}"
    counted = sum(_windows_in(n, settings) for n, settings in stretches)
    if len(windows) != counted:
        return f"{len(windows)} windows judged, the stretches between restarts hold {counted}"
    broken_after_s = min(stretches[-1][0] / FS_HZ, feed.broken_s)
    broken_start_s = blocks[-1].start_s + blocks[-1].n_samples / FS_HZ - feed.broken_s
    if broken_after_s >= CONFIRM_WITHIN_S and not any(kind == "CONFIRMED" and time_s >= broken_start_s for kind, time_s in got):
        return f"the broken spring not confirmed: {broken_after_s:.0f} s of it after the last restart of the windows"
    time.sleep(0.05)  # threads that were told to end may take a moment to go
    after = _threads_and_fds()
    if after != before:
        return f"left behind: {after[0] - before[0]} threads, {after[1] - before[1]} file descriptors"
    return None


def _monitor_settings(settings: Settings, state: Path) -> MonitorSettings:
    return parse_config(settings.text(state), "fuzz").monitor_settings(None, FS_HZ)


def _windows_in(n_samples: int, settings: Settings) -> int:
    window_n, hop_n = round(settings.window_s * FS_HZ), round(settings.hop_s * FS_HZ)
    return (n_samples - window_n) // hop_n + 1 if n_samples >= window_n else 0


TARGETS = [fuzz_core.Target("reload", generate, run)]
