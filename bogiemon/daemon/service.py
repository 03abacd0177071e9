"""The service: `bogiemon run` under systemd (Type=notify) or by hand.

The main thread only supervises: it tells systemd READY=1 once the first block went through,
pings WATCHDOG=1 only while blocks keep moving (a stalled source or core lets systemd restart
us), publishes STATUS= with the latest window, reloads on SIGHUP (a bad new config is logged
and rejected, the old one keeps running) and drains on SIGTERM. Signal handlers only set a flag and
write a byte to a pipe the main thread sleeps on (daemon/signals.py).
While it runs, numpy's BLAS keeps to one thread (daemon/blas.py says why).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

from bogiemon.daemon.blas import limit_blas_threads
from bogiemon.daemon.config import BogiemonConfig, ConfigError, StateConfig, load_config_and_files
from bogiemon.daemon.delivery import Delivery
from bogiemon.daemon.logs import get_logger
from bogiemon.judgement.models import excitation_of
from bogiemon.daemon.monitor import Monitor
from bogiemon.judgement.verdict import WindowVerdict
from bogiemon.judgement.vocabulary import LoadState, Method
from bogiemon.daemon.notify import Notifier
from bogiemon.daemon.pipeline import Pipeline
from bogiemon.daemon.recorder import Recorder
from bogiemon.daemon.ringbuffer import BlockRing
from bogiemon.daemon.signals import Requests
from bogiemon.daemon.sinks import EventSink, LogSink
from bogiemon.daemon.startup import Snapshot, check_start
from bogiemon.daemon.statedir import give_back
from bogiemon.daemon.store import EventStore, StoreError
from bogiemon.drivers.base import Source
from bogiemon.drivers.recording import RecordingError

SourceFactory = Callable[[BogiemonConfig], Source]
STATUS_PERIOD_S = 10.0
EXIT_OK, EXIT_INTERNAL_ERROR = 0, 1
# The event store refused commits and the service stopped holding what it refused (README,
# "When the storage fails"): non-zero, so that systemd restarts it and the journal shows why.
EXIT_STORE_FAILED = 3


def status_line(report: WindowVerdict | None, monitor: Monitor) -> str:
    """One line for systemctl status: mode, what gated or failed, and the judged indicators."""
    if report is None:
        return f"running, first window not complete yet ({monitor.counters.samples} samples)"
    parts = [f"mode {report.mode}", f"window ending {time.strftime('%H:%M:%S', time.gmtime(report.window.end_s))}Z"]
    if report.health.gate is not None:
        parts.append(f"gated: {report.health.gate.value}")
    if not report.health.sensors_ok:
        parts.append("sensor fault: " + ", ".join(f"{ch} {'/'.join(p.value for p in ps)}" for ch, ps in report.health.problems.items()))
    if report.unfamiliar is not None:
        parts.append(f"not judged: the running is unlike the commissioning's ({report.unfamiliar})")
    elif report.judgement is not None and report.judgement.level_margin > 1.0:
        parts.append(f"levels x{report.judgement.level_margin:.2f} (excitation {excitation_of(report.window):.2f} m/s^2 outside the commissioning's)")
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


class Service:
    def __init__(
        self,
        config_path: str | Path | None,
        source_factory: SourceFactory,
        load: str | None = None,
        notifier: Notifier | None = None,
        sinks: list[EventSink] | None = None,
        observers: list[Callable[[WindowVerdict], None]] | None = None,
        state_dir: str | Path | None = None,
        requests: Requests | None = None,
    ) -> None:
        # Asked of the service by a signal or another thread (request_stop, request_reload). `bogiemon
        # run` makes them and installs their handlers before the config is read (a signal during the
        # start is the service's too); otherwise the service has its own.
        self.requests = requests if requests is not None else Requests()
        self._own_requests = requests is None
        self.config_path = config_path
        self.state_dir = Path(state_dir) if state_dir is not None else None
        self.config, files = self._load_config()  # a bad config at start is a user error: exit 2
        self.snapshot = Snapshot.of(self.config, files)  # the config and the files it names, as the service runs them
        self.load = load
        self.source_factory = source_factory
        self.notifier = notifier or Notifier()
        self.sinks = sinks if sinks is not None else [LogSink()]
        self.observers = observers or []
        self.recorder: Recorder | None = None  # [recorder] enabled: it taps the monitor's blocks and windows
        self._log = get_logger(component="service")

    def _load_config(self) -> tuple[BogiemonConfig, tuple[Path, ...]]:
        """The config file and the files it read, with the state directory of the command line in
        place of its own (at every reload too: `--state-dir` holds for the whole run, as the file's
        [state] would)."""
        config, files = load_config_and_files(self.config_path)
        if self.state_dir is None:
            return config, files
        return config.model_copy(update={"state": StateConfig(directory=self.state_dir)}), files

    def _warn_if_not_commissioned(self, config: BogiemonConfig) -> None:
        """The fused method without this wagon's calibration judges against the fleet's population
        baseline, which misses most faults: say so at every start, where a keeper looks."""
        missing = [ld for ld in LoadState if ld not in config.decision.fused] if config.decision.method is Method.FUSED else []
        if missing:
            self._log.warning(
                "not commissioned: no calibration of this wagon for the load state(s) "
                f"{', '.join(missing)}; they are judged against the fleet's population baseline, which misses most faults. "
                "Record the healthy wagon and run `bogiemon calibrate` (README: commissioning)",
                loads=missing,
            )

    def install_signal_handlers(self) -> None:
        """SIGTERM and SIGINT stop the service, SIGHUP reloads it (the main thread only); they are
        ignored from the moment it stops (daemon/signals.py says why)."""
        self.requests.install()

    def request_stop(self) -> None:
        """Stop, as SIGTERM does (from any thread)."""
        self.requests.request_stop()

    def request_reload(self) -> None:
        """Reload the config, as SIGHUP does (from any thread)."""
        self.requests.request_reload()

    def run(self) -> int:
        try:
            return self._run()
        finally:
            self.requests.quiet()  # the handlers, if installed, ignore the signals from now on ...
            if self._own_requests:
                self.requests.close()  # ... so that none writes to the pipe's closed, maybe reused, descriptor

    def _run(self) -> int:
        if self.requests.stop:  # asked to stop while it started (the config read): nothing opened yet
            self._log.info("stopped before it started")
            return EXIT_OK
        # What bogiemon left on a disk filled to its last pages (a recording killed in the middle of its
        # write, recordings of an earlier version) would not even let the store open, and the
        # recorder starts after it: their room first (daemon/statedir.py, docs/recorder.md).
        give_back(self.config)
        # What check-config checks, run here first: a file the config names that cannot be used
        # (a DBC, a recording, a damaged store) stops the start before anything is opened for writing.
        for problem in check_start(self.config):
            self._log.warning(problem)
        try:
            store = EventStore(self.config.state.directory)
        except StoreError as exc:
            # A store bogiemon refuses (damaged, empty, newer, unwritable) is left as it is; the
            # keeper reads why in the journal at crit and in systemctl status. The CLI prints the
            # same line and exits 2.
            self._log.critical("cannot open the event store, not starting", error=str(exc))
            self.notifier.status(f"not started: {exc}")
            raise
        self.delivery = Delivery(store.path.parent)  # MQTT and CAN alarms, each in a thread of its own
        # Live data cannot be read twice: what the store refuses is held and retried, not dropped.
        monitor = Monitor(
            self.config.monitor_settings(self.load), store, [*self.sinks, self.delivery], self.observers, hold_uncommitted=True
        )
        self.delivery.start(self.config, monitor)
        self._apply_recorder(None, monitor, self.config)
        self._log.info(
            "starting", config=str(self.config_path or "default"), config_hash=self.config.digest(),
            state=str(store.path), mode=monitor.mode, load=self.load or self.config.decision.load,
        )  # fmt: skip
        self._warn_if_not_commissioned(self.config)
        # Before the first product: OpenBLAS's pool would spin a core after every large one.
        blas = limit_blas_threads(1)
        self._log.info("BLAS kept to one thread", libraries=blas.libraries)
        pipeline = self._start_pipeline(monitor)
        ready = False
        last_status = 0.0
        store_failures = 0  # the monitor's count when STATUS last told it: a new failure is told at once
        tick_s = min(1.0, (self.notifier.watchdog_interval_s or 2.0) / 2)
        try:
            while True:
                self.requests.wait(tick_s)
                if self.requests.stop:
                    break
                if self.requests.take_reload():
                    pipeline = self._reload(pipeline, monitor)
                if not ready and pipeline.first_block.is_set():
                    ready = True
                    self.notifier.ready(status="receiving data")
                    self._log.info("ready", fs_hz=pipeline.source.fs_hz)
                if self._data_moves(pipeline):
                    self.notifier.watchdog()
                if time.monotonic() - last_status >= STATUS_PERIOD_S or monitor.store_failures != store_failures:
                    last_status, store_failures = time.monotonic(), monitor.store_failures
                    line = status_line(monitor.latest, monitor)
                    if monitor.store_failure is not None:
                        line = f"EVENT STORE FAILING, {len(monitor.held)} events held uncommitted ({monitor.store_failure}); {line}"
                    self.notifier.status(line)
                if pipeline.finished.is_set():  # a finite source ended, or a thread failed
                    break
        finally:
            self.requests.quiet()  # stopping: a signal now is neither a reload nor a second stop
            self.notifier.stopping()
            pipeline.stop()
            pipeline.source.close()
            if self.recorder is not None:
                self.recorder.close()  # writes what is queued, logs its counters
            self.delivery.close()  # says "offline"; what is undelivered stays in the outbox
            monitor.save_state()  # with the held events, a last try; a refusal is logged at crit, never raised
            store.close()
            blas.restore()  # the process may go on (tests, the bench): its own setting again
            self._log.info("stopped", counters=vars(monitor.counters), source=pipeline.source.counters.as_dict(), ring=vars(pipeline.ring.counters))
        if monitor.store_failure is not None or isinstance(pipeline.error, StoreError):
            self._log.critical(
                "stopped after the event store refused commits: the events held are lost, the last committed alarm state stands",
                lost_events=len(monitor.held), lost_kinds=[e.kind.value for e in monitor.held],
                error=monitor.store_failure or str(pipeline.error),
            )  # fmt: skip
            return EXIT_STORE_FAILED
        if isinstance(pipeline.error, RecordingError):
            # A replayed recording bad further in: the windows before it were judged and their events
            # committed; the file is named as a user error (one line, exit 2), never as a crash.
            self._log.error("the recording cannot be read on, stopping", error=str(pipeline.error))
            raise pipeline.error
        return EXIT_INTERNAL_ERROR if pipeline.error is not None else EXIT_OK

    def _start_pipeline(self, monitor: Monitor) -> Pipeline:
        source = self.source_factory(self.config)
        capacity_n = max(1, int(self.config.pipeline.ring_capacity_s * source.fs_hz))
        ring = BlockRing(capacity_n, backpressure=source.finite)
        pipeline = Pipeline(source, monitor, ring)
        pipeline.start()
        return pipeline

    def _apply_recorder(self, pipeline: Pipeline | None, monitor: Monitor, config: BogiemonConfig) -> None:
        """Attach the recorder the config asks for, in place of the running one if its settings
        changed (a new one starts with an empty ring); the old one finishes its writes."""
        settings = config.recorder_settings()
        old = self.recorder
        if (old.settings if old is not None else None) == settings:
            return
        new = Recorder(settings) if settings is not None else None

        def swap(m: Monitor) -> None:
            if old is not None:
                m.taps.remove(old.on_block)
                m.observers.remove(old.on_window)
            if new is not None:
                m.taps.append(new.on_block)
                m.observers.append(new.on_window)

        if pipeline is None:  # not started yet
            swap(monitor)
        else:
            pipeline.with_monitor(swap)  # between two blocks
        self.recorder = new
        if old is not None:
            old.close()
        if new is not None:
            r = new.settings
            self._log.info("recorder started", directory=str(r.directory), lead_in_s=r.lead_in_s,
                           periodic_every_h=r.periodic_every_h, max_total_bytes=r.max_total_bytes)  # fmt: skip

    def _data_moves(self, pipeline: Pipeline) -> bool:
        interval_s = self.notifier.watchdog_interval_s
        if interval_s is None or pipeline.error is not None:
            return False
        # A block must have passed within half the watchdog interval: otherwise systemd decides.
        return time.monotonic() - pipeline.last_progress_monotonic < interval_s / 2

    def _reload(self, pipeline: Pipeline, monitor: Monitor) -> Pipeline:
        """SIGHUP: load, validate and apply the config file again; returns the pipeline that runs.

        Any failure rejects the reload, not only a ConfigError: a file that cannot be read, a
        setting that cannot be built, a source or a delivery part that will not start. It is
        logged and told to systemd, and the running config stays; what was applied of the new
        one is put back. The service goes on either way.
        """
        self.notifier.reloading()
        old, old_settings = self.config, monitor.settings

        def reject(exc: Exception, stage: str) -> None:
            # A ConfigError is written for the keeper; anything else is a bug: its class says which.
            reason = str(exc) if isinstance(exc, ConfigError) else f"{type(exc).__name__}: {exc}"
            self._log.error("reload rejected, keeping the running config", reason=reason, stage=stage)
            self.notifier.ready(status="reload rejected: " + " ".join(line.strip() for line in reason.splitlines()))

        try:
            new, files = self._load_config()
            snapshot = Snapshot.of(new, files)
            changed = self.snapshot.changed(snapshot)
            if changed:
                # The files it names are opened and parsed as at a start: a DBC, a model file or a
                # recording that cannot be used rejects the whole reload.
                for problem in check_start(new):
                    self._log.warning("reload: " + problem)
                # Everything the monitor takes, built before anything changes (the fused model's fit included).
                settings = new.monitor_settings(self.load, pipeline.source.fs_hz)
        except Exception as exc:
            reject(exc, "load")
            return pipeline
        if not changed:
            # The same config, includes and named files: nothing to apply, nothing restarts. A reload
            # storm (a tool reloading on every change of a folder, say) must never make the monitor blind.
            self._log.info("reloaded", config_hash=new.digest(), files_hash=snapshot.digest, unchanged=True, windows_restart=False)
            self.notifier.ready(status="reloaded: the config is unchanged")
            return pipeline
        restart_source = bool(changed & {"source", "pipeline", "duty"})  # its settings, or a file it reads (a DBC, the recording), or its duty cycle
        source_stopped = False
        restarted: list[bool] = []
        try:
            self.config = new
            pipeline.with_monitor(lambda m: restarted.append(m.reconfigure(settings)))
            self.delivery.apply(new, changed)  # restarts the publisher or the CAN alarms only if their sections changed
            if restart_source:
                source_stopped = True
                pipeline.stop()
                pipeline.source.close()
                monitor.new_stream()  # the new source's first samples: a new segment, not a loss
                pipeline = self._start_pipeline(monitor)
        except Exception as exc:
            try:  # what ran before, as it ran: the monitor's settings (its alarm state carries over), delivery, source
                self.config = old
                pipeline.with_monitor(lambda m: m.reconfigure(old_settings))
                self.delivery.apply(old, changed)
                if source_stopped:
                    pipeline = self._start_pipeline(monitor)
            except Exception as restore_exc:
                self._log.critical("reload failed and the running config could not be restored, stopping",
                                   reason=f"{type(exc).__name__}: {exc}", restore=f"{type(restore_exc).__name__}: {restore_exc}")  # fmt: skip
                raise
            reject(exc, "apply")
            return pipeline
        try:
            self._apply_recorder(pipeline, monitor, new)
        except Exception as exc:  # noqa: BLE001 - recordings are a nicety: the new config runs without the change
            self._log.error("recorder not reconfigured, the running one goes on", error=f"{type(exc).__name__}: {exc}")
        self.snapshot = snapshot
        if "state" in changed:
            self._log.warning("state.directory changes take effect at the next start", kept=str(old.state.directory))
        # Said when the windows restart (the processing, the sensors or the source changed): the next
        # judged window is then a whole window of data away.
        windows_restart = bool(restarted and restarted[0]) or restart_source
        self._log.info("reloaded", config_hash=new.digest(), files_hash=snapshot.digest, changed=sorted(changed), windows_restart=windows_restart)
        self._warn_if_not_commissioned(new)
        restart_text = f": the windows restart, the next is judged {new.processing.window_s:g} s of data from now"
        self.notifier.ready(status="reloaded" + (restart_text if windows_restart else ""))
        return pipeline
