"""`bogiemon demo`: the main job on the bundled simulator, live on the terminal (`make demo`).

The daemon's own service runs with config/demo.toml: a healthy stretch, then a spring breaks.
A line per window shows the time, the decision mode and the judged indicators; events stand
out; a summary ends it. The service's JSON log goes to demo.log in the state directory.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from bogiemon.judgement.events import ConfirmedDetails, EventKind

if TYPE_CHECKING:
    from bogiemon.judgement.verdict import WindowVerdict


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("demo", help="run the daemon on the bundled simulator: a healthy stretch, then a broken spring")
    p.add_argument("--config", help="demo config (default: the shipped config/demo.toml)")
    p.add_argument(
        "--calibration",
        help="the demo wagon's commissioning, a `bogiemon calibrate` fragment (default: the shipped config/demo_calibration.toml; "
        "'none' runs uncommissioned)",
    )
    p.add_argument("--state-dir", help="keep the event store and the log here (default: a temporary folder)")
    p.set_defaults(run=run)


class LiveDisplay:
    """Prints one line per window and the events as they are committed."""

    def __init__(self, duration_s: float, fault_at_s: float | None, out: TextIO = sys.stdout) -> None:
        self.duration_s = duration_s
        self.fault_at_s = fault_at_s
        self.out = out
        self.t0_s: float | None = None
        self.confirmed_at_s: float | None = None
        self.events: list[str] = []

    def __call__(self, report: WindowVerdict) -> None:
        w = report.window
        if self.t0_s is None:
            self.t0_s = w.start_s  # the first window starts with the run
        end_s = w.end_s - self.t0_s
        done = min(1.0, end_s / self.duration_s)
        bar = "#" * int(20 * done) + "-" * (20 - int(20 * done))
        if report.judgement is not None:
            j = report.judgement
            values = "  ".join(f"{name} {value:+.4f}" for name, value in j.values.items())
            if math.isfinite(j.alarm_ratio):
                values += f"  ({100 * j.alarm_ratio:3.0f} % of alarm)"
            if math.isfinite(j.trend):
                values += f"  trend {j.trend:.2f}"
        elif report.health.gate is not None:
            values = f"not judged: {report.health.gate.value}"
        else:
            values = "not judged: sensor problem"
        self.out.write(f"  {end_s:6.0f} s [{bar}]  {report.mode:<9}  {values}\n")
        for event in report.events:
            fired = ", ".join(f"{k} {v:+.3f}" for k, v in event.indicators.items())
            line = f"{event.kind.value} ({event.severity.value}) at {end_s:.0f} s: {fired}"
            diagnosis = event.details.diagnosis if isinstance(event.details, ConfirmedDetails) else None
            if diagnosis is not None and diagnosis.corners:
                line += f"; corner {diagnosis.corner} ({diagnosis.best_match})"
            elif diagnosis is not None:
                # The signs do not single a pair out: say so, and why (best_match names no pair then).
                line += f"; corner unknown ({diagnosis.best_match or 'no evidence'})"
            self.events.append(line)
            self.out.write(f"  >>> {line}\n")
            if event.kind is EventKind.CONFIRMED and self.confirmed_at_s is None:
                self.confirmed_at_s = end_s
        self.out.flush()


def run(args: argparse.Namespace) -> int:
    from bogiemon.daemon.config import SimulatedSourceConfig, load_config
    from bogiemon.daemon.logs import configure_logging
    from bogiemon.daemon.service import Service
    from bogiemon.daemon.sources import open_source

    shipped = resources.files("bogiemon.config")
    demo_path = Path(args.config) if args.config else Path(str(shipped.joinpath("demo.toml")))
    calibration = None if args.calibration == "none" else Path(args.calibration or str(shipped.joinpath("demo_calibration.toml")))
    with tempfile.TemporaryDirectory(prefix="bogiemon-demo-") as scratch:
        state_dir = Path(args.state_dir) if args.state_dir else Path(scratch)
        state_dir.mkdir(parents=True, exist_ok=True)
        # The demo file, with the state directory of this run: the daemon reads it like any config.
        run_config = state_dir / "demo-run.toml"
        # The demo wagon was commissioned like any other: its calibration is included after the demo file.
        includes = ", ".join(f'"{p.resolve()}"' for p in (demo_path, calibration) if p is not None)
        # Its includes are the shipped files, outside the state directory: allowed here by name.
        run_config.write_text(f"allow_absolute_includes = true\ninclude = [{includes}]\n\n[state]\ndirectory = \"{state_dir.resolve()}\"\n")
        config = load_config(run_config)
        src = config.source
        if not isinstance(src, SimulatedSourceConfig):
            print(f"bogiemon demo: {demo_path} must use [source] kind = \"simulated\"", file=sys.stderr)
            return 2
        print(
            f"bogiemon demo: {src.load} load, {src.speed_kmh:g} km/h on {src.track}, {src.duration_s:g} s at {src.rate:g}x real time; "
            + (f"{', '.join(src.faults)} from {src.fault_at_s:g} s" if src.faults else "healthy")
        )
        p = config.processing
        print(f"windows of {p.window_s:g} s every {p.hop_s:g} s; alarm after {config.decision.confirm_k} of {config.decision.confirm_n} windows")
        if calibration is not None:
            print(f"the wagon is commissioned: {calibration.name} (`bogiemon calibrate` on two hours of it running healthy)")
        print("simulating the run (the first demo on a machine also compiles the simulator, ~15 s) ...", flush=True)
        display = LiveDisplay(src.duration_s, src.fault_at_s if src.faults else None)
        with (state_dir / "demo.log").open("w") as log:
            configure_logging(stream=log)
            service = Service(run_config, open_source, observers=[display], sinks=[])
            service.install_signal_handlers()
            status = service.run()
        print("\nsummary")
        for line in display.events or ["no events"]:
            print(f"  {line}")
        if display.confirmed_at_s is not None and src.faults:
            print(f"  the alarm was confirmed {display.confirmed_at_s - src.fault_at_s:.0f} s after the spring broke ({src.fault_at_s:g} s)")
        elif src.faults:
            print("  the fault was not confirmed within the run")
        if args.state_dir:
            print(f"  events kept in {state_dir}/events.sqlite3: bogiemon events --state-dir {state_dir}")
        else:
            print("  the events were kept in a temporary folder, gone now (--state-dir DIR keeps them)")
        return status
