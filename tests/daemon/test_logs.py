"""Log lines: JSON with the syslog priority prefix that journald reads."""

import io
import json

from bogiemon.judgement.events import EventKind
from bogiemon.daemon.logs import configure_logging
from bogiemon.daemon.sinks import LogSink
from tests.judgement.event_examples import event_of


def test_events_are_logged_with_a_priority_journalctl_filters_on() -> None:
    out = io.StringIO()
    configure_logging(out)
    sink = LogSink()
    for kind in (EventKind.CONFIRMED, EventKind.SUSPECTED, EventKind.CLEARED):
        sink.publish(event_of(kind, 5.0, {"i2_norm": 0.1}, config_hash="h"))
    lines = out.getvalue().splitlines()
    assert [line[:3] for line in lines] == ["<2>", "<4>", "<6>"]
    record = json.loads(lines[0][3:])
    assert record["event"] == "CONFIRMED" and record["severity"] == "alarm" and record["indicators"] == {"i2_norm": 0.1}
    assert record["config_hash"] == "h" and "timestamp" in record and len(record["event_id"]) == 32
    assert record["details"]["alarm_windows"] == {"k": 3, "n": 5} and record["details"]["trigger"] == "windows"  # as JSON, as the store keeps it
