"""Structured logging for the service: one JSON object per line on stdout, syslog priority first.

journald reads a leading "<N>" on each stdout line as the line's syslog priority (SyslogLevelPrefix=
yes, its default), so `journalctl -p warning` shows warnings, suspension alarms and sensor faults,
and `journalctl -o cat` shows the JSON. Without journald the prefix is harmless and easy to strip.
"""

from __future__ import annotations

import logging
import sys
from typing import Any, TextIO

import structlog

# The one table of syslog priorities (an event's severity names its level: judgement/events.py).
_PRIORITY = {"debug": 7, "info": 6, "warning": 4, "error": 3, "critical": 2}


def _syslog_prefix(_logger: Any, method_name: str, rendered: str) -> str:
    return f"<{_PRIORITY.get(method_name, 6)}>{rendered}"


class _LineLogger:
    """Writes each rendered line and flushes, so a line reaches the journal as it happens."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream

    def msg(self, line: str) -> None:
        self._stream.write(line + "\n")
        self._stream.flush()

    debug = info = warning = error = critical = msg


def configure_logging(stream: TextIO | None = None, level: str = "info") -> None:
    """Route structlog through JSON lines with a syslog priority prefix (call once per process)."""
    out = stream if stream is not None else sys.stdout
    structlog.configure(
        processors=[
            structlog.processors.add_log_level,
            structlog.processors.TimeStamper(fmt="iso", utc=True),
            structlog.processors.dict_tracebacks,
            structlog.processors.JSONRenderer(sort_keys=False),
            # After the renderer the event is its JSON line, which structlog's Processor type cannot say.
            _syslog_prefix,  # type: ignore[list-item]
        ],
        wrapper_class=structlog.make_filtering_bound_logger(_level_number(level)),
        logger_factory=lambda *_: _LineLogger(out),
        cache_logger_on_first_use=False,
    )


def _level_number(level: str) -> int:
    return logging.getLevelNamesMapping()[level.upper()]


def get_logger(**initial: Any) -> Any:
    return structlog.get_logger(**initial)
