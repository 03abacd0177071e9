"""`bogiemon fleet simulate|analyze|judge|calibrate|report`: the back office (docs/fleet.md).

    bogiemon fleet simulate FLEET [--wagons N --days D]   a simulated fleet's recordings tree
    bogiemon fleet analyze FLEET -o WINDOWS [--scheduler tcp://HOST:PORT] [--workers N]
    bogiemon fleet calibrate WAGON --fleet FLEET --windows WINDOWS [--days D ...]  (or --uncommissioned)
    bogiemon fleet judge WINDOWS -o JUDGED [--fleet FLEET]
    bogiemon fleet report JUDGED -o REPORT [--since YYYY-MM-DD]
"""

from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("fleet", help="the back office: re-analyse a fleet's recordings on Dask, judge every wagon, report")
    fleet_sub = p.add_subparsers(dest="fleet_command", metavar="STEP", required=True)

    s = fleet_sub.add_parser("simulate", help="write a simulated fleet's recordings tree (healthy wagons, a few faults, a sensor damage)")
    s.add_argument("root", metavar="FLEET", help="the folder to write (must not exist or be empty)")
    s.add_argument("--wagons", type=int, default=8, help="wagons (default 8)")
    s.add_argument("--days", type=int, default=3, help="days of running per wagon (default 3)")
    s.add_argument("--seed", type=int, default=2026, help="the fleet's seed (default 2026)")
    s.add_argument("--commission-runs", type=int, default=6, help="healthy runs on the first day, the commissioning (default 6)")
    s.add_argument("--runs-per-day", type=int, default=3, help="runs on every later day (default 3)")
    s.add_argument("--run-s", type=float, default=600.0, help="the length of a run in seconds (default 600)")
    s.set_defaults(run=run_simulate)

    a = fleet_sub.add_parser("analyze", help="every wagon-day through the detection core on Dask, to a Parquet windows dataset")
    a.add_argument("root", metavar="FLEET", help="the recordings tree: FLEET/<wagon-id>/<YYYY-MM-DD>/ (docs/fleet-formats.md)")
    a.add_argument("-o", "--output", required=True, metavar="WINDOWS", help="the windows dataset (resumed where it stopped)")
    a.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="an existing Dask scheduler (default: a local cluster, one worker per core)")
    a.add_argument("--workers", type=int, help="workers of the local cluster (default: one per core)")
    a.add_argument("--redo", action="store_true", help="analyse every partition again, even those that are up to date")
    a.set_defaults(run=run_analyze)

    c = fleet_sub.add_parser("calibrate", help="commission a wagon from its own analysed days (writes FLEET/<wagon>/calibration.toml)")
    c.add_argument("wagon", nargs="?", metavar="WAGON", help="the wagon id (or --uncommissioned for every wagon without a calibration)")
    c.add_argument("--fleet", required=True, metavar="FLEET", help="the recordings tree")
    c.add_argument("--windows", required=True, metavar="WINDOWS", help="its windows dataset (`fleet analyze`)")
    c.add_argument("--days", nargs="+", default=(), metavar="YYYY-MM-DD", help="the healthy days to learn from (default: the first analysed day)")
    c.add_argument("--first-days", type=int, default=1, help="without --days: this many of the first analysed days (default 1)")
    c.add_argument("--uncommissioned", action="store_true", help="every wagon without a calibration.toml")
    c.add_argument("--load", choices=("auto", "full", "tare"), default="auto",
                   help="the load state of those days (default auto: split by the shipped load model, a prior; state it when you know it)")
    c.add_argument("--force", action="store_true", help="replace an existing calibration")
    c.set_defaults(run=run_calibrate)

    j = fleet_sub.add_parser("judge", help="the daemon's decision over every wagon's windows, in time order: events and states")
    j.add_argument("windows", metavar="WINDOWS", help="the windows dataset of `fleet analyze`")
    j.add_argument("-o", "--output", required=True, metavar="JUDGED", help="the folder for wagons.json, events.jsonl and the series")
    j.add_argument("--fleet", metavar="FLEET", help="the recordings tree with the wagons' configs (default: the one analysed)")
    j.set_defaults(run=run_judge)

    r = fleet_sub.add_parser("report", help="the work list: a page per fleet and per wagon, CSV and JSON, no server")
    r.add_argument("judged", metavar="JUDGED", help="the folder of `fleet judge`")
    r.add_argument("-o", "--output", required=True, metavar="REPORT",
                   help="the report's folder: index.html (the work list), worklist.csv, worklist.json, wagons/<id>.html")
    r.add_argument("--title", help="the page's title (default: the fleet's name)")
    r.add_argument("--since", metavar="YYYY-MM-DD",
                   help="tell what changed since this date, UTC (default: since the previous report in REPORT, else over the last day)")
    r.set_defaults(run=run_report)


def _progress(label: str):  # type: ignore[no-untyped-def]
    from bogiemon.cli.progress import ProgressBar

    bar = ProgressBar(sys.stderr, label)

    def report(done: int, total: int) -> None:
        bar(done / total if total else 1.0)
        if done == total:
            bar.close()

    return report


def run_simulate(args: argparse.Namespace) -> int:
    from pathlib import Path

    from bogiemon.cli.progress import ProgressBar
    from bogiemon.lab.fleetsim import DEMO_FAULTS, DEMO_SENSOR_DAMAGES, FleetPlan, FleetSimError, simulate_fleet

    root = Path(args.root)
    if args.wagons < 1 or args.days < 1:
        raise FleetSimError("--wagons and --days must be at least 1")
    # The demo's faults and sensor damage, those of them that fall on the wagons and days asked for.
    faults = tuple(f for f in DEMO_FAULTS if f.wagon < args.wagons and f.day < args.days)
    damages = tuple(d for d in DEMO_SENSOR_DAMAGES if d.wagon < args.wagons and d.day < args.days)
    plan = FleetPlan(n_wagons=args.wagons, days=args.days, fleet_seed=args.seed, commission_runs=args.commission_runs,
                     runs_per_day=args.runs_per_day, run_s=args.run_s, faults=faults, sensor_damages=damages)  # fmt: skip
    bar = ProgressBar(sys.stderr, "simulating the fleet")
    truth = simulate_fleet(root, plan, progress=bar)
    bar.close()
    recordings = sum(len(w.runs) for w in truth.wagons)
    print(f"{root}: {args.wagons} wagons x {args.days} days, {recordings} recordings; what was simulated is in {root / 'truth.json'}")
    for w in truth.wagons:
        wrong = [f"{f.key} at {f.severity:g} at {f.corner.value} from {plan.date(f.day)}" for f in w.faults]
        wrong += [f"{d.damage} from {plan.date(d.day)}" for d in w.sensor_damages]
        print(f"  {w.wagon_id} ({w.load}): {'; '.join(wrong) or 'healthy'}")
    return 0


def run_analyze(args: argparse.Namespace) -> int:
    from bogiemon.fleet.analyze import analyze_fleet
    from bogiemon.fleet.paths import shown

    summary = analyze_fleet(args.root, args.output, scheduler=args.scheduler, n_workers=args.workers,
                            progress=_progress("analysing wagon-days"), redo=args.redo)  # fmt: skip
    hours = summary.recorded_s / 3600
    print(
        f"{shown(summary.out_dir)}: {summary.wagons} wagons, {summary.partitions} wagon-days ({summary.analysed} analysed, "
        f"{summary.reused} up to date), {summary.windows} windows; {hours:.1f} h of recording in {summary.elapsed_s:.1f} s"
        + (f" on {summary.workers} workers" if summary.workers else "")
    )
    _print_issues(summary.repaired, "partition(s) damaged or replaced, analysed again")
    _print_issues(summary.issues)
    if summary.windows == 0:  # a cron job must learn that nothing came of it
        print(
            f"bogiemon: analysed nothing: no wagon-day of {shown(summary.root)} gave a window "
            + ("(see the reasons above)" if summary.issues else "(no recordings found: is FLEET the fleet's folder?)"),
            file=sys.stderr,
        )
        return 1
    return 0


def run_calibrate(args: argparse.Namespace) -> int:
    from bogiemon.daemon.calibrate import CalibrationError
    from bogiemon.fleet.calibrate import calibrate_wagon
    from bogiemon.fleet.layout import FleetError, scan_fleet
    from bogiemon.fleet.paths import shown

    if bool(args.wagon) == bool(args.uncommissioned):
        raise FleetError("name one WAGON, or pass --uncommissioned for every wagon without a calibration")
    ids = [args.wagon] if args.wagon else [w.wagon_id for w in scan_fleet(args.fleet).wagons if w.calibration_path is None]
    failed = 0
    for wagon_id in ids:
        try:
            done = calibrate_wagon(args.fleet, args.windows, wagon_id, days=args.days, first_days=args.first_days, force=args.force, load=args.load)
        except (CalibrationError, FleetError) as exc:
            if args.wagon:
                raise
            failed += 1
            print(f"{wagon_id}: not calibrated: {exc}", file=sys.stderr)
            continue
        loads = ", ".join(f"{c.load} ({c.n_judged} windows)" for c in done.result.loads)
        print(f"{wagon_id}: {shown(done.path)} from {', '.join(done.days)}: {loads}")
    return 1 if failed else 0


def run_judge(args: argparse.Namespace) -> int:
    from bogiemon.fleet.judge import judge_fleet
    from bogiemon.fleet.paths import shown

    summary = judge_fleet(args.windows, args.output, fleet_root=args.fleet, progress=_progress("judging wagons"))
    states = ", ".join(f"{n} {state}" for state, n in sorted(summary.states.items()))
    print(f"{shown(summary.out_dir)}: {summary.wagons} wagons ({states}), {summary.events} events, in {summary.elapsed_s:.1f} s")
    _print_issues(summary.issues)
    return 0


def run_report(args: argparse.Namespace) -> int:
    from bogiemon.fleet.paths import shown
    from bogiemon.fleet.report import write_report

    done = write_report(args.judged, args.output, title=args.title, since=args.since)
    states = ", ".join(f"{n} {state}" for state, n in done.states.items() if n)
    print(f"{shown(done.index)}: the work list of {done.wagons} wagons ({states}); {done.changed} changed {done.compared_with}; "
          f"open it in a browser (worklist.csv beside it)")
    return 0


def _print_issues(issues, what: str = "input(s) skipped") -> None:  # type: ignore[no-untyped-def]
    if not issues:
        return
    print(f"{len(issues)} {what}:", file=sys.stderr)
    for issue in issues[:20]:
        print(f"  {issue.path}: {issue.reason}", file=sys.stderr)
    if len(issues) > 20:
        print(f"  ... and {len(issues) - 20} more (all of them in the output's summary)", file=sys.stderr)
