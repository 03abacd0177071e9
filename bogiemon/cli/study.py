"""`bogiemon study -o DIR [--quick]`: the detection study (the paper's Table 4 on the simulator) and its report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bogiemon.cli.progress import ProgressBar, check_report_folder


class StudyError(ValueError):
    """A study that cannot run as asked (bad output folder, bad window lengths); the message says why."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "study",
        help="run the detection study on the simulator and write its report (Table 4, figures, defaults)",
        description="Simulate the reference paper's experiment matrix (both loads, the healthy wagon and every "
        "fault case, several speeds, tracks and seeds), compute the indicators with the detection core, judge "
        "each case by the study's stated rule and write README.md, defaults.md, table4.json and figures/ into "
        "DIR. The full matrix takes several minutes on two cores; --quick runs a small subset.",
    )
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="folder for the report (created if missing)")
    p.add_argument("--quick", action="store_true", help="a small subset: one speed and track, fewer runs, one window length")
    p.add_argument("--config", help="config file for the processing settings and sensors (default: shipped)")
    p.add_argument(
        "--windows-s",
        metavar="W,...",
        help="window lengths to compare, seconds (default 30,60,120; the config's window_s is always included)",
    )
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures (no matplotlib needed)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    p.set_defaults(run=run)


def _window_lengths(text: str | None) -> tuple[float, ...]:
    if text is None:
        return (30.0, 60.0, 120.0)
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise StudyError(f"--windows-s '{text}': expected seconds separated by commas, e.g. 30,60,120") from None
    if not values or any(not v > 0 for v in values):
        raise StudyError(f"--windows-s '{text}': window lengths must be positive")
    return values


def run(args: argparse.Namespace) -> int:
    # The simulator (numba) and the study are imported only by this command.
    from bogiemon.daemon.config import load_config
    from bogiemon.lab.study import StudyPlan, run_study, window_settings, write_report

    out = Path(args.output)
    check_report_folder(out, not args.no_figures, StudyError)
    config = load_config(args.config)
    settings = config.processing_settings()
    lengths_s = _window_lengths(args.windows_s)
    try:
        plan = StudyPlan.quick(settings.window_s) if args.quick else StudyPlan.default(lengths_s)
        window_settings(plan, settings)
    except ValueError as exc:  # window lengths that do not fit the hop, the lags or the runs
        raise StudyError(f"{exc}: choose other --windows-s or processing settings") from None
    command = " ".join(
        ["bogiemon study", "-o", str(out)]
        + (["--quick"] if args.quick else [])
        + (["--windows-s", args.windows_s] if args.windows_s and not args.quick else [])
        + (["--config", args.config] if args.config else [])
    )
    bar = None if args.quiet else ProgressBar(sys.stderr, f"study ({plan.name}, {len(plan.runs())} runs)")
    try:
        result = run_study(plan, settings, config.bogie_geometry(), bar)
    finally:
        if bar is not None:
            bar.close()
    try:
        out.mkdir(exist_ok=True)
        doc = write_report(
            result, out, command=command, confirm_k=config.decision.confirm_k, confirm_n=config.decision.confirm_n,
            figures=not args.no_figures, configured=config.decision_settings().thresholds,
            min_excitation_rms_mps2=config.health.min_excitation_rms_mps2,
        )  # fmt: skip
    except OSError as exc:
        raise StudyError(f"{out}: cannot write the report: {exc.strerror or exc}") from None
    if not args.quiet:
        agreement = doc["agreement"]
        print(
            f"{out}: {len(result.runs)} runs in {doc['timing']['total_s'] / 60:.1f} min; Table 4: "
            f"{agreement['agree']} of {agreement['cells']} cells agree with the paper; report in {out / 'README.md'}"
        )
    return 0
