"""Log lines: JSON with the syslog priority prefix that journald reads."""

import io
import json

from bogiemon.judgement.events import Event, EventKind, Severity
from bogiemon.daemon.logs import configure_logging
from bogiemon.daemon.sinks import LogSink


def test_events_are_logged_with_a_priority_journalctl_filters_on() -> None:
    out = io.StringIO()
    configure_logging(out)
    sink = LogSink()
    for kind, severity in [(EventKind.CONFIRMED, Severity.ALARM), (EventKind.SUSPECTED, Severity.WARNING), (EventKind.CLEARED, Severity.INFO)]:
        sink.publish(Event(time_s=5.0, kind=kind, severity=severity, config_hash="h", indicators={"i2_norm": 0.1}))
    lines = out.getvalue().splitlines()
    assert [line[:3] for line in lines] == ["<2>", "<4>", "<6>"]
    record = json.loads(lines[0][3:])
    assert record["event"] == "CONFIRMED" and record["severity"] == "alarm" and record["indicators"] == {"i2_norm": 0.1}
    assert record["config_hash"] == "h" and "timestamp" in record and len(record["event_id"]) == 32
