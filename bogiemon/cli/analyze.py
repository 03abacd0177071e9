"""`bogiemon analyze FILE... [--config F] [--json]`: the indicators of every window of recordings."""

from __future__ import annotations

import argparse
import json
import sys

from bogiemon.cli.mapping import add_mapping_arguments, with_mapping

_COLUMNS = ("start_s", "end_s", "I1", "I2", "I3", "I4", "I1n", "I2n", "I3n", "I4n")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("analyze", help="compute the fault indicators of recordings, window by window")
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="recordings (.csv, .csv.gz, .parquet, MF4 of signals) or CAN logs (candump -L .log, .asc, .blf, .trc, "
                        "python-can's .csv and .db, MF4 bus logs; .gz where they are text), in time order; a folder: its files in name order")  # fmt: skip
    p.add_argument("--config", help="config file (default: the shipped default config)")
    p.add_argument("--json", action="store_true", help="one JSON object per window, with every field")
    add_mapping_arguments(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from bogiemon.cli.replay import timing_text
    from bogiemon.daemon.analysis import analyze_recording, describe_source, indicators_as_dict, open_recording
    from bogiemon.daemon.config import load_config
    from bogiemon.drivers.recording import MAX_ACCEL_MPS2, MIN_ACCEL_MPS2, RecordingError
    from bogiemon.drivers.sniff import expand_folders

    config = with_mapping(load_config(args.config), args)
    out = sys.stdout
    try:
        for path in expand_folders(args.files, RecordingError):  # a folder: its recordings, in name order
            source = open_recording(path, config)
            try:
                if not args.json:
                    p = config.processing
                    out.write(
                        f"# {path}: {describe_source(source)}; "
                        f"windows of {p.window_s:g} s every {p.hop_s:g} s, lags +/-{p.max_lag_s:g} s\n"
                    )
                    out.write("".join(f"{c:>12}" for c in _COLUMNS).lstrip() + "\n")
                for ind in analyze_recording(source, config):
                    if args.json:
                        out.write(json.dumps({"file": str(path), **indicators_as_dict(ind)}) + "\n")
                    else:
                        values = (ind.start_s, ind.end_s, *ind.raw, *ind.normalised)
                        out.write(f"{values[0]:10.3f}  {values[1]:10.3f}" + "".join(f"{v:12.4e}" for v in values[2:]) + "\n")
            finally:
                source.close()
            if not args.json:
                out.write("".join(f"# {line}\n" for line in timing_text(str(path), source.counters.extra)))
            clipped = source.counters.extra.get("clipped_samples", 0)
            if clipped and not args.json:
                out.write(
                    f"# {path}: {clipped} samples beyond the converter's range clipped to its full scale "
                    f"({MIN_ACCEL_MPS2:.4f} .. {MAX_ACCEL_MPS2:+.4f} m/s^2)\n"
                )
    finally:
        out.flush()  # the windows before a bad row come out before its error
    return 0
