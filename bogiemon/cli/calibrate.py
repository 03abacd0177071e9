"""`bogiemon calibrate --full RECORDINGS... --tare RECORDINGS... -o calibration.toml` (or RECORDINGS... --load
auto|full|tare): a wagon's healthy baseline, per load state."""

from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("calibrate", help="learn the wagon's healthy baseline (fused score and thresholds) from recordings of it")
    p.add_argument("files", nargs="*", metavar="RECORDING", help="recordings of the healthy wagon in the load state --load names")
    p.add_argument(
        "--load", choices=("auto", "full", "tare"),
        help="the load state of the RECORDINGs (auto: split by the shipped load model, a prior fitted on the simulator; "
        "prefer --full and --tare on a real wagon)",
    )  # fmt: skip
    p.add_argument("--full", nargs="+", default=(), metavar="RECORDING", help="recordings of the healthy wagon loaded")
    p.add_argument("--tare", nargs="+", default=(), metavar="RECORDING", help="recordings of the healthy wagon empty")
    p.add_argument("-o", "--output", required=True, help="the config fragment to write (TOML)")
    p.add_argument("--config", help="config file (default: the shipped default config)")
    p.add_argument("--indicators", help="comma-separated indicators (default: those the config thresholds for --load)")
    p.add_argument("--warning-rate", type=float, default=1e-2, help="per-window false-warning target (default 0.01)")
    p.add_argument("--alarm-rate", type=float, default=1e-4, help="per-window false-alarm target (default 0.0001)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from bogiemon.daemon.calibrate import calibrate, fragment
    from bogiemon.daemon.config import load_config
    from bogiemon.drivers.atomic import write_text_atomically
    from bogiemon.daemon.calibrate import CalibrationError, calibrate_loads

    config = load_config(args.config)
    names = [n.strip() for n in args.indicators.split(",")] if args.indicators else None
    per_load = {ld: list(paths) for ld, paths in (("full", args.full), ("tare", args.tare)) if paths}
    if bool(per_load) == bool(args.files or args.load):
        raise CalibrationError("give recordings with --load (RECORDING... --load full|tare|auto), or per load with --full ... and --tare ...")
    if per_load:
        result = calibrate_loads(per_load, config, names, args.warning_rate, args.alarm_rate)
    else:
        if not args.files or not args.load:
            raise CalibrationError("RECORDING... needs --load full, tare or auto (or use --full ... --tare ...)")
        result = calibrate(args.files, config, args.load, names, args.warning_rate, args.alarm_rate)
    write_text_atomically(args.output, fragment(result))
    print(f"{result.n_judged} of {result.n_windows} windows judged; wrote {args.output}", file=sys.stderr)
    if result.load_note:
        print(f"  load states: {result.load_note}", file=sys.stderr)
    if result.discriminant is not None:
        d = result.discriminant
        print(f"  full and tare lie {d.separation:.1f} of their scatter apart; windows within {d.margin:.1f} of the middle are not judged", file=sys.stderr)
    elif len(result.loads) == 2:
        print("  full and tare lie too close to draw a line between them: the nearest state decides", file=sys.stderr)
    if result.structure is not None:
        checks = ", ".join(result.structure.checks) or "none (no SWAPPED or INVERTED will be reported)"
        print(f"  sensor structure checks in force: {checks}", file=sys.stderr)
    if result.noise_floor is not None:
        floors = ", ".join(f"a{c + 1} {v ** 0.5 * 1e3:.3g}" for c, v in enumerate(result.noise_floor.psd))
        print(f"  sensors' noise floors (smallest seen, mm/s^2 per sqrt(Hz)): {floors}", file=sys.stderr)
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
