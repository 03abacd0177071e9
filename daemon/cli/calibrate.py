"""`bogiemon calibrate RECORDINGS... --load auto|full|tare -o calibration.toml`: a wagon's healthy baseline."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("calibrate", help="learn the wagon's healthy baseline (fused score and thresholds) from recordings of it")
    p.add_argument("files", nargs="+", metavar="RECORDING", help="CSV recordings of the healthy wagon")
    p.add_argument(
        "--load", required=True, choices=("auto", "full", "tare"),
        help="the load state of the recordings (auto: each window's estimated state; every state with enough windows is calibrated)",
    )  # fmt: skip
    p.add_argument("-o", "--output", required=True, help="the config fragment to write (TOML)")
    p.add_argument("--config", help="config file (default: the shipped default config)")
    p.add_argument("--indicators", help="comma-separated indicators (default: those the config thresholds for --load)")
    p.add_argument("--warning-rate", type=float, default=1e-2, help="per-window false-warning target (default 0.01)")
    p.add_argument("--alarm-rate", type=float, default=1e-4, help="per-window false-alarm target (default 0.0001)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from bogiemon.daemon.calibrate import calibrate, fragment
    from bogiemon.daemon.config import load_config
    config = load_config(args.config)
    names = [n.strip() for n in args.indicators.split(",")] if args.indicators else None
    result = calibrate(args.files, config, args.load, names, args.warning_rate, args.alarm_rate)
    Path(args.output).write_text(fragment(result), encoding="utf-8")
    print(f"{result.n_judged} of {result.n_windows} windows judged; wrote {args.output}", file=sys.stderr)
    for ld, n in result.skipped.items():
        print(f"  {ld}: only {n} windows, not calibrated (record longer runs in that load state)", file=sys.stderr)
    for load in result.loads:
        print(f"  {load.load} ({load.n_judged} windows):", file=sys.stderr)
        if load.fused is not None:
            f = load.fused
            lv = f.levels
            print(f"    fused score  warning {lv.warning:.4g}  alarm {lv.alarm:.4g}; trend warning {lv.trend_warning:.4g}  alarm {lv.trend_alarm:.4g}"
                  f"  (median calibration score {f.median_score:.3g}, levels x{f.level_factor:.2f})", file=sys.stderr)  # fmt: skip
        for c in load.indicators:
            t = c.threshold
            print(f"    {c.name:<12} center {t.center:+.4g}  warning {t.warning:.4g}  alarm {t.alarm:.4g}  (robust sigma {c.robust_sigma:.3g}, largest healthy deviation {c.max_deviation:.3g})", file=sys.stderr)
    return 0
