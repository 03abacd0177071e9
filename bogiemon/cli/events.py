"""`bogiemon events [--since T] [--json]`: list the events in the event store."""

from __future__ import annotations

import argparse
import json
import re
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bogiemon.judgement.events import Event

_RELATIVE = re.compile(r"^(\d+(?:\.\d+)?)\s*(s|min|h|d)$")
_UNIT_S = {"s": 1, "min": 60, "h": 3600, "d": 86400}


class TimeArgumentError(ValueError):
    """A --since value that is neither a time nor a duration."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("events", help="list the events the daemon committed")
    p.add_argument("--config", help="config file naming the state directory (default: the shipped default)")
    p.add_argument("--state-dir", help="the state directory, overriding the config's")
    p.add_argument("--since", help="only events at or after T: ISO 8601 (2026-11-20T08:00Z), Unix seconds, or ago (2h, 30min, 7d)")
    p.add_argument("--json", action="store_true", help="one JSON object per event")
    p.set_defaults(run=run)


def parse_since(text: str, now_s: float) -> float:
    """A --since value as Unix seconds."""
    text = text.strip()
    if m := _RELATIVE.match(text):
        return now_s - float(m.group(1)) * _UNIT_S[m.group(2)]
    try:
        return float(text)
    except ValueError:
        pass
    try:
        moment = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise TimeArgumentError(f"--since: '{text}' is not a time (2026-11-20T08:00Z, Unix seconds) or a duration (2h, 30min, 7d)") from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return moment.timestamp()


def format_time(time_s: float) -> str:
    """Unix seconds as ISO 8601 UTC; a time no calendar holds (inf, nan, 1e300: a store written
    before times were checked at the source) as its number, so that listing a store never fails."""
    try:
        return datetime.fromtimestamp(time_s, tz=UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    except (OverflowError, OSError, ValueError):
        return f"time_s={time_s!r}"


def format_event(event: Event) -> str:
    when = format_time(event.time_s)
    values = " ".join(f"{k}={v:.4g}" for k, v in event.indicators.items())
    from bogiemon.judgement.events import SensorFaultDetails

    extra = ""
    if isinstance(event.details, SensorFaultDetails):
        extra = " " + " ".join(f"{ch}:{'/'.join(p)}" for ch, p in event.details.problems.items())
    return f"{when}  {event.kind.value:<14} {event.severity.value:<7} {values}{extra}".rstrip()


def run(args: argparse.Namespace) -> int:
    from bogiemon.daemon.config import load_config
    from bogiemon.daemon.event_json import event_body
    from bogiemon.daemon.store import EventStore
    state_dir = Path(args.state_dir) if args.state_dir else load_config(args.config).state.directory
    since_s = parse_since(args.since, time.time()) if args.since else None
    store = EventStore(state_dir, readonly=True)
    try:
        for event in store.events(since_s):
            print(json.dumps(event_body(event)) if args.json else format_event(event))
    finally:
        store.close()
    return 0
