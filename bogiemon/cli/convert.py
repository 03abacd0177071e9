"""`bogiemon convert INPUT -o OUTPUT [--config F] [--dbc F --layout L] [--channel can0]`: any recording or
CAN log bogiemon reads, written as a recording (.csv, .csv.gz, .parquet) or a candump -L log (.log)."""

from __future__ import annotations

import argparse
import sys
import time

from bogiemon.cli.mapping import add_mapping_arguments, with_mapping
from bogiemon.cli.play import LAYOUT_CHOICES

PROGRESS_AFTER_S = 2.0


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("convert", help="write any recording or CAN log as CSV, Parquet or a candump -L log")
    p.add_argument("input", metavar="INPUT", help="a recording (.csv, .csv.gz, .parquet, MF4 of signals) or a CAN log of any format replay reads")
    p.add_argument("-o", "--output", required=True, metavar="OUTPUT", help="the file to write: .csv, .csv.gz, .parquet, or .log (candump -L)")
    p.add_argument("--config", help="config file: its [source] mapping, unit, layout and DBC (default: the shipped default config)")
    p.add_argument("--layout", choices=LAYOUT_CHOICES, help="the frame layout of a CAN log read or written (default: the config's)")
    p.add_argument("--dbc", help="the DBC of a CAN log read or written (default: the config's, else the shipped one)")
    p.add_argument("--channel", default="can0", help="the interface named in a candump log's lines (default can0)")
    add_mapping_arguments(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from bogiemon.cli.progress import ProgressBar
    from bogiemon.daemon.config import load_config
    from bogiemon.daemon.sources import open_replay_source, replay_source_config
    from bogiemon.drivers.candb import load_layout
    from bogiemon.drivers.convert import convert, output_kind

    config = with_mapping(load_config(args.config), args)
    src = replay_source_config(args.input, config)
    src = src.model_copy(update={k: v for k, v in (("layout", args.layout), ("dbc_path", args.dbc)) if v is not None})
    output_kind(args.output)  # a wrong name before anything is read
    source = open_replay_source(args.input, config.model_copy(update={"source": src}))
    layout = load_layout(src.dbc_path or None, src.layout) if output_kind(args.output) == "candump" else None
    bar = ProgressBar(sys.stderr, f"converting {args.input}")
    started_s = time.monotonic()

    def progress(fraction: float) -> None:  # a long file's only: a short one is done before a line would help
        if time.monotonic() - started_s > PROGRESS_AFTER_S:
            bar(fraction)

    try:
        stats = convert(source, args.output, layout, progress=progress, channel=args.channel)
    finally:
        bar.close()
    gaps = f", {stats.segments - 1} gap(s) kept" if stats.segments > 1 else ""
    print(f"# {args.output}: {stats.samples} samples at {stats.fs_hz:.6g} Hz from {args.input}{gaps}", file=sys.stderr)
    return 0
