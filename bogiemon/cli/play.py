"""`bogiemon play FILE --interface socketcan --channel vcan0 [--rate N] [--layout hub|per-node] [--ready-file PATH]`.

Puts a recording (CSV, .csv.gz or Parquet; or a simulated run) on a CAN bus as the sensor hub or nodes would send it,
encoded with the DBC, at real-time pace or N times faster (--rate 0: as fast as possible).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from bogiemon.drivers.canbus import KINDS

# drivers.candb.LAYOUTS, written out: importing candb (cantools, numpy) here would slow every
# command's start-up; a test checks the two agree.
LAYOUT_CHOICES = ("hub", "per-node")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("play", help="send a recording on a CAN bus as the sensors would (bench, tests)")
    p.add_argument("file", metavar="FILE", help="a recording (.csv, .csv.gz, .parquet, MF4 of signals) or a CAN log (decoded with --dbc)")
    p.add_argument("--interface", choices=sorted(KINDS), default="socketcan",
                   help="python-can interface (default socketcan; virtual: a bus inside this process only, which no other "
                        "program hears: for tests)")  # fmt: skip
    p.add_argument("--channel", default="vcan0", help="CAN interface or virtual channel (default vcan0)")
    p.add_argument("--rate", type=float, default=1.0,
                   help="pace: 1 real time (default), N times faster, 0 as fast as possible")  # fmt: skip
    p.add_argument("--layout", choices=LAYOUT_CHOICES, default="hub", help="frame layout of the DBC (default hub)")
    p.add_argument("--dbc", help="DBC file (default: the shipped config/bogiemon.dbc)")
    p.add_argument("--ready-file", metavar="PATH", type=Path,
                   help="once the bus is open, just before the first frame, write PATH (one line: interface "
                        "and channel), so a script or a test waits for the player instead of sleeping; "
                        "remove it before starting")  # fmt: skip
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from bogiemon.daemon.config import load_config
    from bogiemon.drivers.candb import load_layout
    from bogiemon.drivers.player import PlayError, open_player_bus, play, read_samples

    if args.rate < 0:
        raise PlayError(f"--rate must be 0 (as fast as possible) or positive, got {args.rate:g}")
    # python-can logs a failed bind at ERROR before raising; our PlayError says it in one line,
    # so keep Python's last-resort handler from printing a second one.
    logging.getLogger("can").addHandler(logging.NullHandler())
    layout = load_layout(args.dbc, args.layout)
    recording = read_samples(args.file, layout, load_config(None).processing.fs_hz)
    bus = open_player_bus(args.interface, args.channel)
    try:
        if args.ready_file is not None:
            try:
                args.ready_file.write_text(f"{args.interface} {args.channel}\n", encoding="utf-8")
            except OSError as exc:
                raise PlayError(f"--ready-file {args.ready_file}: cannot write: {exc.strerror or exc}") from None
        stats = play(bus, layout, recording.accel_mps2, recording.fs_hz, rate=args.rate)
    finally:
        bus.shutdown()
    print(
        f"# {args.file}: {stats.instants} samples at {recording.fs_hz:.6g} Hz as {stats.frames} {layout.name} frames "
        f"on {args.interface} {args.channel} in {stats.wall_s:.2f} s",
        file=sys.stderr,
    )
    if recording.gaps:
        print(f"# {args.file}: {recording.gaps} gap(s) in it were played as if the samples had followed on", file=sys.stderr)
    if args.interface == "virtual":
        print(
            f"# note: the virtual interface is a bus inside this process: no other program heard these frames. "
            f"To feed a gateway on this machine use a vcan interface (--interface socketcan --channel vcan0), or "
            f"make a CAN log with `bogiemon convert {args.file} -o run.log`",
            file=sys.stderr,
        )
    return 0
