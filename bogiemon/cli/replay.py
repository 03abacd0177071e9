"""`bogiemon replay RECORDING... [--config F] [--load auto|full|tare] [--json] [--realtime] [--duty]`."""

from __future__ import annotations

import argparse
import json
import sys

from collections.abc import Mapping
from typing import TYPE_CHECKING

from bogiemon.cli.events import format_event
from bogiemon.cli.mapping import add_mapping_arguments, with_mapping

if TYPE_CHECKING:
    from bogiemon.daemon.sinks import EventSink


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("replay", help="run recordings (CSV, Parquet or CAN logs) through the daemon's pipeline and print its events")
    p.add_argument("files", nargs="+", metavar="RECORDING", help="recordings (.csv, .csv.gz, .parquet, MF4) or CAN logs (.log, .asc, .blf, ...), in time order; a folder: its recordings in name order")
    p.add_argument("--config", help="config file (default: the shipped default config)")
    p.add_argument("--load", choices=("auto", "full", "tare"), help="load state, overriding decision.load (auto: estimated from the signals)")
    p.add_argument("--json", action="store_true", help="events as JSON lines")
    p.add_argument("--realtime", action="store_true", help="pace the recordings at real time instead of as fast as possible")
    p.add_argument("--state-dir", help="keep the event store here (default: a temporary one)")
    p.add_argument("--duty", action="store_true",
                   help="read the recordings on the config's [duty] cycle, as the daemon would on the wagon "
                        "(its rests skip samples): what the duty cycle costs the detection")  # fmt: skip
    add_mapping_arguments(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from bogiemon.daemon.config import load_config
    from bogiemon.daemon.replay import replay

    from bogiemon.drivers.recording import RecordingError
    from bogiemon.drivers.sniff import expand_folders

    config = with_mapping(load_config(args.config), args)
    files = expand_folders(args.files, RecordingError)  # a folder: its recordings, in name order
    summary = replay(files, config, args.load, args.realtime, args.state_dir, [print_sink(args.json)], duty=args.duty)
    c = summary.counters
    print(
        f"replayed {summary.recordings} recording(s): {c.windows} windows, {c.judged} judged, {c.gated} gated, "
        f"{c.sensor_fault_windows} with a sensor problem, {c.events} events; final mode {summary.final_mode}",
        file=sys.stderr,
    )
    for report in summary.reports:  # what a source counted and skipped, one line per recording
        line = report.skipped_text()
        if line is not None:
            print(line, file=sys.stderr)
        clipped = report.source_counters.get("clipped_samples", 0)
        if clipped:
            print(clipped_text(report.path, clipped), file=sys.stderr)
        for line in timing_text(report.path, report.source_counters):
            print(line, file=sys.stderr)
    return 0


def timing_text(path: str, counters: Mapping[str, int]) -> list[str]:
    """The lines saying a recording's jittered time stamps were resampled and its gaps found."""
    lines = []
    resampled = counters.get("resampled_samples", 0)
    if resampled:
        lines.append(f"{path}: {resampled} samples with jittered time stamps resampled onto the recording's nominal grid")
    gaps = counters.get("recording_gaps", 0)
    if gaps:
        what = "a gap" if gaps == 1 else f"{gaps} gaps"
        lines.append(f"{path}: {what} in the time stamps (samples missing): a new segment after each, no window spans one")
    return lines


def clipped_text(path: str, clipped: int) -> str:
    """The line saying a recording's samples beyond the converter's range were clipped."""
    from bogiemon.drivers.recording import MAX_ACCEL_MPS2, MIN_ACCEL_MPS2

    what = "sample" if clipped == 1 else "samples"
    return f"{path}: clipped {clipped} {what} beyond the converter's range to its full scale ({MIN_ACCEL_MPS2:.4f} .. {MAX_ACCEL_MPS2:+.4f} m/s^2)"


def print_sink(as_json: bool) -> EventSink:
    """A sink that prints each committed event, as a line or as JSON."""
    from bogiemon.daemon.event_json import event_body
    from bogiemon.daemon.sinks import EventSink
    from bogiemon.judgement.events import Event

    class PrintSink(EventSink):
        def publish(self, event: Event) -> None:
            print(json.dumps(event_body(event)) if as_json else format_event(event), flush=True)

    return PrintSink()
