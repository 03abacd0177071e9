"""`bogiemon simulate -o FILE.csv [...]`: a simulated recording of the monitored (leading) bogie, with its sidecar."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bogiemon.cli.progress import ProgressBar

_TRACKS = "perfect, erri-low, erri-high, fra-4, fra-5, fra-6"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate a Y25 wagon and write a CSV recording of the leading bogie's three sensors",
        description="Simulate the vertical dynamics of a Y25 wagon on random track and write the three "
        "accelerometers of its leading bogie as a CSV recording (FILE.csv) with the whole scenario "
        "in FILE.json. Sensor corners, spacing and sample rate come from the config.",
    )
    p.add_argument("-o", "--output", required=True, metavar="FILE.csv", help="recording to write (sidecar: FILE.json)")
    p.add_argument("--load", choices=("full", "tare"), default="full", help="carbody 80.6 t or 6.86 t (default full)")
    p.add_argument(
        "--model",
        choices=("a", "b"),
        default="a",
        help="wagon model: a (docs/simulator.md, default) or b, built independently of it (docs/simulator-b.md)",
    )
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--speed-kmh", type=float, default=80.0, help="constant speed (default 80)")
    speed.add_argument(
        "--speed-profile",
        metavar="T:V,...",
        help="piecewise-linear speed, time_s:speed_kmh points, e.g. '0:60,120:100' (held after the last point)",
    )
    p.add_argument("--track", default="erri-low", help=f"track irregularity spectrum: {_TRACKS} (default erri-low)")
    p.add_argument("--duration-s", type=float, default=120.0, help="length of the recording (default 120)")
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="SPEC",
        help="KIND:POSITION:SEVERITY@CORNER, repeatable: type_a:rear_outer:0.0@leading-left, "
        "type_b::0.5@trailing-right, custom:KZ_N_PER_M:FS_N@leading-right; prefix the corner "
        "with trailing-bogie: for the wagon's other bogie",
    )
    p.add_argument("--fault-at-s", type=float, default=0.0, metavar="T",
                   help="the faults appear T seconds into the recording, healthy before (default 0: from the start)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="seed of the track and the sensor noise (default 0)")
    p.add_argument("--config", help="config file for the sensor corners, spacing and fs_hz (default: shipped)")
    p.add_argument("--fs-hz", type=float, help="sample rate (default: the config's processing.fs_hz)")
    p.add_argument("--noise-mps2", type=float, default=0.0, help="sensor white noise, standard deviation")
    p.add_argument("--bias-mps2", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar="B", help="bias of a1 a2 a3")
    p.add_argument("--quantum-mps2", type=float, default=0.0, help="quantisation step of the sensors (0: none)")
    p.add_argument("--max-step-s", type=float, default=2.5e-4, help="longest integration step (default 0.25 ms)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from bogiemon.daemon.config import load_config
    from bogiemon.simulator.errors import SimulationError
    from bogiemon.simulator.scenario import Scenario, SpeedProfile
    from bogiemon.simulator.sensors import SensorModel
    from bogiemon.simulator.suspension import parse_fault

    if args.output.lower().endswith(".json"):
        raise SimulationError(f"{args.output}: the recording is CSV (its sidecar gets the .json name): use FILE.csv")
    if not Path(args.output).resolve().parent.is_dir():
        raise SimulationError(f"{args.output}: the folder does not exist: create it or choose another -o")
    config = load_config(args.config)
    speed = SpeedProfile.parse(args.speed_profile) if args.speed_profile else SpeedProfile.constant(args.speed_kmh)
    scenario = Scenario(
        load=args.load,
        speed=speed,
        track=args.track,
        duration_s=args.duration_s,
        seed=args.seed,
        faults=tuple(parse_fault(f) for f in args.fault),
        fault_onset_s=args.fault_at_s,
        fs_hz=args.fs_hz if args.fs_hz is not None else config.processing.fs_hz,
        geometry=config.bogie_geometry(),
        sensor=SensorModel(noise_mps2=args.noise_mps2, bias_mps2=tuple(args.bias_mps2), quantum_mps2=args.quantum_mps2),
        max_step_s=args.max_step_s,
        model=args.model,
    )
    # The simulator's kernel (numba) once the scenario is known to be one: a bad argument is told
    # without loading it.
    from bogiemon.simulator.run import simulate, write_recording

    bar = ProgressBar(sys.stderr, f"simulating {scenario.duration_s:g} s") if sys.stderr.isatty() and not args.quiet else None
    try:
        result = simulate(scenario, bar)
    finally:
        if bar is not None:
            bar.close()
    try:
        sidecar = write_recording(result, args.output)
    except OSError as exc:
        raise SimulationError(f"{args.output}: cannot write the recording: {exc.strerror or exc}") from None
    if not args.quiet:
        faults = ", ".join(f.spec() for f in scenario.faults) or "healthy"
        if scenario.fault_onset_s > 0:
            faults += f" from {scenario.fault_onset_s:g} s"
        print(
            f"{args.output}: {scenario.n_samples} samples at {scenario.fs_hz:g} Hz ({scenario.duration_s:g} s), "
            f"{scenario.load} load, {speed.spec()} km/h on {scenario.track}, seed {scenario.seed}, {faults}, "
            f"model {scenario.model}; scenario in {sidecar}"
        )
    return 0
