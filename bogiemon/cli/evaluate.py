"""`bogiemon evaluate -o DIR [--quick] [--fit-models] [--data FILE]`: the robustness evaluation and its report;
`bogiemon evaluate --transfer -o DIR [--quick | --full] [--data FILE]`: the priors of each wagon model judged on the other."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bogiemon.cli.progress import ProgressBar, check_report_folder


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "evaluate",
        help="evaluate the detection methods on a varied simulated fleet and write the report",
        description="Simulate a fleet of wagons that differ as real ones do (masses, springs, dampers, sensors) "
        "over varied speeds, tracks and directions, commission each on healthy runs, then judge healthy, "
        "faulty and damaged-sensor runs with each of the daemon's detection methods, and write README.md, "
        "results.json and figures/ into DIR. The default plan simulates about 444 hours of running "
        "(about 40 minutes on two cores); --quick a small one.",
    )
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="folder for the report (created if missing)")
    p.add_argument("--quick", action="store_true", help="a small plan: 2 wagons, short runs, one run per cell (with --transfer: one wagon)")
    p.add_argument(
        "--transfer",
        action="store_true",
        help="instead: fit the priors on the training fleet of each wagon model (A, B) in turn and judge the daemon's "
        "default method with them on both models' evaluation fleets, against the robustness targets (README.md and "
        "results.json; the config folder is not touched)",
    )
    p.add_argument("--full", action="store_true", help="with --transfer: the plan with 100 h of healthy running per model (about 90 minutes from nothing)")
    p.add_argument("--config", help="config file for the processing, health and decision settings (default: shipped)")
    p.add_argument(
        "--fit-models",
        action="store_true",
        help="first fit the shipped models (load state, fused spread and levels) on the plan's training "
        "fleet and write them into bogiemon's config folder",
    )
    p.add_argument(
        "--data",
        metavar="FILE",
        help="cache of the simulated windows: reused when it holds this plan, else written (a pickle: "
        "only load files you made; with --transfer it holds both models')",
    )
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures (no matplotlib needed)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from bogiemon.daemon.config import load_config
    from bogiemon.lab.robust.evaluate import EvaluateError, run_evaluation

    if args.transfer:
        return _transfer(args)
    if args.full:
        raise EvaluateError("--full is a size of the transfer plan: use it with --transfer")
    out = Path(args.output)
    check_report_folder(out, not args.no_figures, EvaluateError)
    command = " ".join(
        ["bogiemon evaluate", "-o", str(out)]
        + (["--quick"] if args.quick else [])
        + (["--fit-models"] if args.fit_models else [])
        + (["--config", args.config] if args.config else [])
    )
    bar = None if args.quiet else ProgressBar(sys.stderr, "evaluate")
    try:
        doc = run_evaluation(
            load_config(args.config), out, command, quick=args.quick, fit_models=args.fit_models,
            data_file=args.data, figures=not args.no_figures, progress=bar,
        )  # fmt: skip
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        default = doc["methods"][-1]
        missed = [t["target"] for t in default["targets"] if not t["met"]]
        print(f"{out}: {doc['simulated_h']:g} h of running evaluated in {doc['elapsed_s'] / 60:.1f} min; default method '{default['method']}': "
              + (f"{len(missed)} target(s) missed: {'; '.join(missed)}" if missed else "every target met") + f"; report in {out / 'README.md'}")  # fmt: skip
    return 0


def _transfer(args: argparse.Namespace) -> int:
    from bogiemon.daemon.config import load_config
    from bogiemon.lab.robust.evaluate import EvaluateError
    from bogiemon.lab.robust.transfer import run_transfer

    if args.fit_models:
        raise EvaluateError("--fit-models with --transfer: the transfer fits its priors into a temporary folder; leave --fit-models out")
    if args.quick and args.full:
        raise EvaluateError("--quick and --full: choose one size of the transfer plan")
    out = Path(args.output)
    check_report_folder(out, False, EvaluateError)
    size = "quick" if args.quick else "full" if args.full else "default"
    command = " ".join(
        ["bogiemon evaluate --transfer", "-o", str(out)]
        + (["--quick"] if args.quick else [])
        + (["--full"] if args.full else [])
        + (["--config", args.config] if args.config else [])
    )
    bar = None if args.quiet else ProgressBar(sys.stderr, "transfer")
    try:
        doc = run_transfer(load_config(args.config), out, command, size=size, data_file=args.data, progress=bar)
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        cross = [f for t in doc["targets"] for f in t["figures"] if f["priors"] != f["evaluated"]]
        missed = sum(f["met"] is False for f in cross)
        print(f"{out}: {sum(doc['simulated_h'].values()):g} h of running on models {', '.join(m.upper() for m in doc['simulated_h'])} in "
              f"{doc['elapsed_s'] / 60:.1f} min; across models {missed} of {len(cross)} target figures missed; report in {out / 'README.md'}")  # fmt: skip
    return 0
