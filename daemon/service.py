"""The service: `bogiemon run` under systemd (Type=notify) or by hand.

The main thread only supervises: it tells systemd READY=1 once the first block went through,
pings WATCHDOG=1 only while blocks keep moving (a stalled source or core lets systemd restart
us), publishes STATUS= with the latest window, reloads on SIGHUP (a bad new config is logged
and rejected, the old one keeps running) and drains on SIGTERM. Signal handlers only set flags.
"""

from __future__ import annotations

import math
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

from bogiemon.daemon.config import BogiemonConfig, ConfigError, load_config
from bogiemon.daemon.delivery import Delivery
from bogiemon.daemon.logs import get_logger
from bogiemon.daemon.monitor import Monitor, WindowReport
from bogiemon.daemon.notify import Notifier
from bogiemon.daemon.pipeline import Pipeline
from bogiemon.daemon.ringbuffer import BlockRing
from bogiemon.daemon.sinks import EventSink, LogSink
from bogiemon.daemon.store import EventStore
from bogiemon.drivers.base import Source

SourceFactory = Callable[[BogiemonConfig], Source]
STATUS_PERIOD_S = 10.0
EXIT_OK, EXIT_INTERNAL_ERROR = 0, 1


def status_line(report: WindowReport | None, monitor: Monitor) -> str:
    """One line for systemctl status: mode, what gated or failed, and the judged indicators."""
    if report is None:
        return f"running, first window not complete yet ({monitor.counters.samples} samples)"
    parts = [f"mode {report.mode}", f"window ending {time.strftime('%H:%M:%S', time.gmtime(report.window.end_s))}Z"]
    if report.health.gate is not None:
        parts.append(f"gated: {report.health.gate.value}")
    if not report.health.sensors_ok:
        parts.append("sensor fault: " + ", ".join(f"{ch} {'/'.join(p.value for p in ps)}" for ch, ps in report.health.problems.items()))
    if report.load is not None:
        parts.append(f"load {report.load}" + (f" (p_full {report.p_full:.2f})" if report.p_full is not None else ""))
    if report.judgement is not None:
        parts += [f"{name} {value:.3g}" for name, value in report.judgement.values.items()]
        if math.isfinite(report.judgement.trend):
            parts.append(f"trend {report.judgement.trend:.3g}")
        if report.judgement.baseline == "population":
            parts.append("not commissioned (population baseline)")
    parts.append(f"{monitor.counters.windows} windows, {monitor.counters.events} events")
    return ", ".join(parts)


@dataclass
class _Flags:
    stop: threading.Event
    reload: threading.Event


class Service:
    def __init__(
        self,
        config_path: str | Path | None,
        source_factory: SourceFactory,
        load: str | None = None,
        notifier: Notifier | None = None,
        sinks: list[EventSink] | None = None,
        observers: list[Callable[[WindowReport], None]] | None = None,
    ) -> None:
        self.config_path = config_path
        self.config = load_config(config_path)  # a bad config at start is a user error: exit 2
        self.load = load
        self.source_factory = source_factory
        self.notifier = notifier or Notifier()
        self.sinks = sinks if sinks is not None else [LogSink()]
        self.observers = observers or []
        self.flags = _Flags(threading.Event(), threading.Event())
        self._log = get_logger(component="service")

    def _warn_if_not_commissioned(self, config: BogiemonConfig) -> None:
        """The fused method without this wagon's calibration judges against the fleet's population
        baseline, which misses most faults: say so at every start, where a keeper looks."""
        missing = [ld for ld in ("full", "tare") if ld not in config.decision.fused] if config.decision.method == "fused" else []
        if missing:
            self._log.warning(
                "not commissioned: no calibration of this wagon for the load state(s) "
                f"{', '.join(missing)}; they are judged against the fleet's population baseline, which misses most faults. "
                "Record the healthy wagon and run `bogiemon calibrate` (README: commissioning)",
                loads=missing,
            )

    def install_signal_handlers(self) -> None:
        def on_stop(signum: int, _frame: FrameType | None) -> None:
            self.flags.stop.set()

        def on_reload(signum: int, _frame: FrameType | None) -> None:
            self.flags.reload.set()

        signal.signal(signal.SIGTERM, on_stop)
        signal.signal(signal.SIGINT, on_stop)
        signal.signal(signal.SIGHUP, on_reload)

    def run(self) -> int:
        store = EventStore(self.config.state.directory)
        self.delivery = Delivery(store.path.parent)  # MQTT and CAN alarms, each in a thread of its own
        monitor = Monitor(self.config.monitor_settings(self.load), store, [*self.sinks, self.delivery], self.observers)
        self.delivery.start(self.config, monitor)
        self._log.info(
            "starting", config=str(self.config_path or "default"), config_hash=self.config.digest(),
            state=str(store.path), mode=monitor.mode, load=self.load or self.config.decision.load,
        )  # fmt: skip
        self._warn_if_not_commissioned(self.config)
        pipeline = self._start_pipeline(monitor)
        ready = False
        last_status = 0.0
        tick_s = min(1.0, (self.notifier.watchdog_interval_s or 2.0) / 2)
        try:
            while not self.flags.stop.wait(tick_s):
                if self.flags.reload.is_set():
                    self.flags.reload.clear()
                    pipeline = self._reload(pipeline, monitor)
                if not ready and pipeline.first_block.is_set():
                    ready = True
                    self.notifier.ready(status="receiving data")
                    self._log.info("ready", fs_hz=pipeline.source.fs_hz)
                if self._data_moves(pipeline):
                    self.notifier.watchdog()
                if time.monotonic() - last_status >= STATUS_PERIOD_S:
                    last_status = time.monotonic()
                    self.notifier.status(status_line(monitor.latest, monitor))
                if pipeline.finished.is_set():  # a finite source ended, or a thread failed
                    break
        finally:
            self.notifier.stopping()
            pipeline.stop()
            pipeline.source.close()
            self.delivery.close()  # says "offline"; what is undelivered stays in the outbox
            monitor.save_state()
            store.close()
            self._log.info("stopped", counters=vars(monitor.counters), source=pipeline.source.counters.as_dict(), ring=vars(pipeline.ring.counters))
        return EXIT_INTERNAL_ERROR if pipeline.error is not None else EXIT_OK

    def _start_pipeline(self, monitor: Monitor) -> Pipeline:
        source = self.source_factory(self.config)
        capacity_n = max(1, int(self.config.pipeline.ring_capacity_s * source.fs_hz))
        ring = BlockRing(capacity_n, backpressure=source.finite)
        pipeline = Pipeline(source, monitor, ring)
        pipeline.start()
        return pipeline

    def _data_moves(self, pipeline: Pipeline) -> bool:
        interval_s = self.notifier.watchdog_interval_s
        if interval_s is None or pipeline.error is not None:
            return False
        # A block must have passed within half the watchdog interval: otherwise systemd decides.
        return time.monotonic() - pipeline.last_progress_monotonic < interval_s / 2

    def _reload(self, pipeline: Pipeline, monitor: Monitor) -> Pipeline:
        self.notifier.reloading()
        try:
            new = load_config(self.config_path)
            new.check_models()
        except ConfigError as exc:
            self._log.error("reload rejected, keeping the running config", reason=str(exc))
            self.notifier.ready(status="reload rejected: " + " ".join(line.strip() for line in str(exc).splitlines()))
            return pipeline
        old, self.config = self.config, new
        if new.state != old.state:
            self._log.warning("state.directory changes take effect at the next start", kept=str(old.state.directory))
        settings = new.monitor_settings(self.load, pipeline.source.fs_hz)
        pipeline.with_monitor(lambda m: m.reconfigure(settings))
        self.delivery.apply(new)  # restarts the publisher or the CAN alarms only if their sections changed
        if new.model_dump().get("source") != old.model_dump().get("source") or new.pipeline != old.pipeline:
            pipeline.stop()
            pipeline.source.close()
            pipeline = self._start_pipeline(monitor)
        self._log.info("reloaded", config_hash=new.digest())
        self._warn_if_not_commissioned(new)
        self.notifier.ready(status="reloaded")
        return pipeline
