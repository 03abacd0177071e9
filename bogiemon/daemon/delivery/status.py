"""The status message of a running monitor (bogiemon.status/1, daemon/messages.py): what the
publisher sends on {prefix}/{wagon_id}/status. The sender's side of the schema: it reads the
monitor and the outbox, which a reader of the messages never needs."""

from __future__ import annotations

from pydantic import ValidationError

from bogiemon.judgement.events import INDICATOR_FIELDS
from bogiemon.daemon.messages import CoverageStatus, LatestWindow, OutboxStatus, SchemaError, StatusMessage, describe
from bogiemon.daemon.monitor import Monitor
from bogiemon.daemon.outbox import OutboxCounts


def status_from_monitor(monitor: Monitor, wagon_id: str, time_s: float, outbox: OutboxCounts) -> StatusMessage:
    """The status message of a running monitor (read from another thread: each field is one read).

    Raises SchemaError when the monitor's state does not fit the schema (a window's times from a
    broken clock, say).
    """
    try:
        return _status_from_monitor(monitor, wagon_id, time_s, outbox)
    except ValidationError as exc:
        raise SchemaError(describe(exc)) from None


def _status_from_monitor(monitor: Monitor, wagon_id: str, time_s: float, outbox: OutboxCounts) -> StatusMessage:
    report = monitor.latest
    window = None
    if report is not None:
        w, health = report.window, report.health
        window = LatestWindow(
            start_s=w.start_s,
            end_s=w.end_s,
            judged=report.judgement is not None,
            gate=None if health.gate is None else health.gate.value,
            sensors_ok=health.sensors_ok,
            sensor_problems={ch: [p.value for p in problems] for ch, problems in health.problems.items()},
            indicators={name: float(getattr(w, name)) for name in INDICATOR_FIELDS},
            rms_mps2=[float(v) for v in w.rms_mps2],
        )
    return StatusMessage(
        wagon_id=wagon_id,
        time_s=time_s,
        mode=report.mode if report is not None else monitor.mode,
        config_hash=monitor.settings.config_hash,
        window=window,
        counters=dict(vars(monitor.counters)),
        coverage=CoverageStatus(
            not_judged=monitor.coverage.reported,
            unjudged_running_s=monitor.coverage.unjudged_running_s,
            last_judged_s=monitor.coverage.since_s,
        ),
        outbox=OutboxStatus(
            pending_events=outbox.pending_events,
            pending_alarms=outbox.pending_alarms,
            pending_status=outbox.pending_status,
            dropped_events=outbox.dropped_events,
            dropped_status=outbox.dropped_status,
        ),
    )


