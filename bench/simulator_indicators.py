"""The simulator against the paper's main effect: indicators of healthy and faulty wagons over seeds.

Prints, per case, the mean and standard deviation over seeds of each run's mean (over its 60 s
windows) of I1..I4 and their normalised variants, as the detection core computes them with the
default config. Run with `.venv/bin/python bench/simulator_indicators.py [--seeds N] [--duration-s S]`.
"""

from __future__ import annotations

import argparse

import numpy as np

from bogiemon.detection import IndicatorStream, ProcessingSettings
from bogiemon.simulator.run import simulate_batch
from bogiemon.simulator.scenario import Scenario
from bogiemon.simulator.suspension import parse_fault

CASES = {
    "full": ["", "type_a:rear_outer:0.0@leading-left", "type_a:front_outer:0.0@leading-left",
             "type_a:front_inner:0.0@leading-left", "type_a:rear_inner:0.0@leading-left",
             "type_a:rear_outer:2.0@leading-left", "type_b::0.5@leading-left", "type_b::1.5@leading-left"],
    "tare": ["", "type_a:rear_outer:0.0@leading-left", "type_a:front_inner:0.0@leading-left", "type_b::0.5@leading-left"],
}  # fmt: skip
NAMES = ("I1", "I2", "I3", "I4", "I1n", "I2n", "I3n", "I4n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=6)
    parser.add_argument("--duration-s", type=float, default=120.0)
    parser.add_argument("--speed-kmh", type=float, default=80.0)
    parser.add_argument("--track", default="erri-low")
    args = parser.parse_args()
    from bogiemon.simulator.scenario import SpeedProfile

    print(f"# {args.seeds} seeds x {args.duration_s:g} s, {args.speed_kmh:g} km/h, {args.track}; mean +/- std over seeds")
    print(f"{'load':<5} {'fault':<38}" + "".join(f"{n:>20}" for n in NAMES))
    for load, faults in CASES.items():
        scenarios = [
            Scenario(
                load=load, seed=seed, duration_s=args.duration_s, track=args.track,
                speed=SpeedProfile.constant(args.speed_kmh), faults=(parse_fault(f),) if f else (),
            )
            for f in faults
            for seed in range(args.seeds)
        ]  # fmt: skip
        results = simulate_batch(scenarios)
        for i, fault in enumerate(faults):
            per_run = []
            for r in results[i * args.seeds : (i + 1) * args.seeds]:
                stream = IndicatorStream(ProcessingSettings(fs_hz=r.scenario.fs_hz, window_s=60.0), r.scenario.geometry)
                per_run.append(np.mean([[*w.raw, *w.normalised] for w in stream.process(r.accel_mps2)], axis=0))
            values = np.array(per_run)
            cells = "".join(f"{m:>+11.2e}+/-{s:<6.1e}" for m, s in zip(values.mean(0), values.std(0), strict=True))
            print(f"{load:<5} {fault or 'healthy':<38}{cells}")


if __name__ == "__main__":
    main()
