"""Running scenarios: one or a batch at once through the compiled kernel, and writing recordings.

    result = simulate(Scenario(load="full", faults=(parse_fault("type_a:rear_outer:0.0@leading-left"),)))
    results = simulate_batch([Scenario(seed=s) for s in range(8)])   # much faster per scenario
    wagon = simulate(Scenario(bogies=2, faults=(parse_fault("type_a:rear_outer:0.0@2:leading-left"),)))  # a1..a3, b1..b3
    write_recording(result, "run.csv")                               # run.csv + run.json
    again = rerun_sidecar("run.json")                                # the same samples

Each run starts with the wagon in static equilibrium on a level stretch; the irregularities fade
in over PREROLL_RAMP_M and the run continues PREROLL_SETTLE_M further before the recording's
time 0 (the pre-roll, at the profile's initial speed), so the recording holds no start-up
transient. All randomness comes from the scenario's seed: the track from one child of
numpy.random.SeedSequence(seed), the sensor noise from the other, bogie 2's (a run of two bogies)
from a third. Scenarios of model "b"
(Scenario.model) run through simulator/model_b instead, with its own pre-roll and seeds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from bogiemon.drivers.recording import write_csv_recording
from bogiemon.simulator import kernel
from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.result import SimulationResult
from bogiemon.simulator.scenario import MONITORED_BOGIE, Scenario, read_sidecar, sidecar_path, speed_table, write_sidecar
from bogiemon.simulator.sensors import anti_alias_sos
from bogiemon.simulator.suspension import BOGIES, CORNER_ORDER
from bogiemon.simulator.track import TrackProfile, generate_track
from bogiemon.simulator.vehicle import State, VehicleModel, build_model, static_equilibrium

PREROLL_RAMP_M = 20.0
PREROLL_SETTLE_M = 20.0
MAX_PREROLL_S = 20.0
TRACK_DS_M = 0.05
TRACK_MARGIN_M = 10.0
CHUNK_S = 2.0
# The whole track is synthesised at once (5 cm steps): beyond this a run would need gigabytes.
MAX_TRACK_M = 400_000.0

Progress = Callable[[float], None]  # called with the fraction done, 0..1


@dataclass
class _Prepared:
    scenario: Scenario
    model: VehicleModel
    rest: State
    track: TrackProfile
    preroll_n: int
    total_n: int  # output samples including the pre-roll
    sensor_rng: np.random.Generator
    # Bogie 2's sensors' noise (a run of two bogies), a stream apart: bogie 1's channels of a
    # two-bogie run are exactly the one-bogie run's.
    sensor_2_rng: np.random.Generator
    healthy_model: VehicleModel  # the suspension before the fault onset (model itself when onset is 0): the standing faults only

    @property
    def onset_n(self) -> int:
        """Output samples (pre-roll included) run on the healthy suspension."""
        return self.preroll_n + self.scenario.onset_sample if self.scenario.fault_onset_s > 0 else 0


def preroll_s(scenario: Scenario, model: VehicleModel) -> float:
    """Seconds run before the recording starts, a whole number of output samples."""
    speed_mps = scenario.speed.speed_mps(0.0)
    if speed_mps <= 0.0:
        return 0.0  # standing: the wagon is at rest on the level stretch, nothing to settle
    distance_m = model.params.axle_offsets_m[-1] + PREROLL_RAMP_M + PREROLL_SETTLE_M
    seconds = min(distance_m / speed_mps, MAX_PREROLL_S)
    return math.ceil(seconds * scenario.fs_hz) / scenario.fs_hz


def _prepare(scenario: Scenario) -> _Prepared:
    assert scenario.parameters is not None
    model = build_model(scenario.parameters, scenario.load, scenario.standing_faults + scenario.faults)
    # spawn(3)'s first two children are spawn(2)'s: the one-bogie streams as they always were.
    track_seed, sensor_seed, sensor_2_seed = np.random.SeedSequence(scenario.seed).spawn(3)
    pre_s = preroll_s(scenario, model)
    preroll_n = int(round(pre_s * scenario.fs_hz))
    first_axle_m = model.params.axle_offsets_m[-1]
    length_m = (
        first_axle_m
        + scenario.speed.speed_mps(0.0) * pre_s
        + scenario.speed.distance_m(scenario.duration_s)
        + TRACK_MARGIN_M
    )
    if length_m > MAX_TRACK_M:
        raise SimulationError(
            f"the run covers {length_m / 1000:.0f} km of track, more than the {MAX_TRACK_M / 1000:.0f} km one run "
            "can hold: split it into shorter scenarios (e.g. consecutive seeds)"
        )
    track = generate_track(
        scenario.track,
        length_m,
        np.random.default_rng(track_seed),
        ds_m=TRACK_DS_M,
        ramp_start_m=first_axle_m + 1.0,
        ramp_length_m=PREROLL_RAMP_M,
    )
    healthy = build_model(scenario.parameters, scenario.load, scenario.standing_faults) if scenario.fault_onset_s > 0 else model
    return _Prepared(
        scenario=scenario,
        model=model,
        healthy_model=healthy,
        rest=static_equilibrium(healthy),  # the run starts on the suspension of its first sample
        track=track,
        preroll_n=preroll_n,
        total_n=preroll_n + scenario.n_samples,
        sensor_rng=np.random.default_rng(sensor_seed),
        sensor_2_rng=np.random.default_rng(sensor_2_seed),
    )


def _derived(prep: _Prepared) -> dict[str, Any]:
    s, model = prep.scenario, prep.model
    compression = -(model.corner_rows() @ prep.rest.q)
    corners = []
    for k, (corner, u) in enumerate(zip(model.corners, compression, strict=True)):
        corners.append(
            {
                "bogie": BOGIES[k // 4],
                "corner": CORNER_ORDER[k % 4].value,
                "Kz_n_per_m": corner.tangent_stiffness_n_per_m(float(u)),
                "Fs_n": corner.fs_n,
                "static_compression_m": float(u),
            }
        )
    return {
        "integration_step_s": s.integration_step_s,
        "oversampling": s.oversampling,
        "preroll_s": prep.preroll_n / s.fs_hz,
        "n_samples": s.n_samples,
        "monitored_bogie": MONITORED_BOGIE,
        "speed_profile": s.speed.spec(),
        "faults": [f.spec() for f in s.faults],
        "corners": corners,
    }


def simulate(scenario: Scenario, progress: Progress | None = None) -> SimulationResult:
    """Run one scenario."""
    return simulate_batch([scenario], progress)[0]


def simulate_batch(scenarios: Sequence[Scenario], progress: Progress | None = None) -> list[SimulationResult]:
    """Run many scenarios together (the kernel's scenario axis, on every core); results in input order.

    Scenarios of the same model (Scenario.model), sample rate and integration step share kernel
    calls; each result is exactly what simulate() gives for that scenario alone.
    """
    groups: dict[tuple[str, float, int, int], list[int]] = {}
    for i, s in enumerate(scenarios):
        groups.setdefault((s.model, s.fs_hz, s.oversampling, s.bogies), []).append(i)
    results: list[SimulationResult | None] = [None] * len(scenarios)
    total_work = sum(float(s.duration_s) for s in scenarios) or 1.0
    done_work = 0.0
    for (model, _, _, _), indices in groups.items():
        group = [scenarios[i] for i in indices]
        weight = sum(s.duration_s for s in group) / total_work

        def report(fraction: float, base: float = done_work, weight: float = weight) -> None:
            if progress is not None:
                progress(min(1.0, base + weight * fraction))

        if model == "b":
            from bogiemon.simulator.model_b.run import run_group as run_group_b  # model B's kernel, when used

            group_results = run_group_b(group, report)
        else:
            group_results = _run_group(group, report)
        for i, result in zip(indices, group_results, strict=True):
            results[i] = result
        done_work += weight
    return [r for r in results if r is not None]


def _run_group(group: list[Scenario], report: Progress) -> list[SimulationResult]:
    preps = [_prepare(s) for s in group]
    n_batch = len(preps)
    fs_hz, factor = group[0].fs_hz, group[0].oversampling
    dt_s = group[0].integration_step_s
    n_channels = 3 * group[0].bogies

    q = np.array([p.rest.q for p in preps])
    v = np.array([p.rest.v for p in preps])
    slider = np.array([p.rest.slider for p in preps])
    front_m = np.array([p.model.params.axle_offsets_m[-1] for p in preps])
    time_s = np.array([-p.preroll_n / fs_hz for p in preps])
    veh = np.array([kernel.pack_vehicle(p.model.params, p.track.ds_m, dt_s) for p in preps])
    corner = np.array([p.healthy_model.corner_table() for p in preps])
    # Output samples until each scenario's faults appear (0: none pending).
    until_onset = np.array([p.onset_n for p in preps], dtype=np.int64)
    speed_t, speed_v, n_speed = speed_table([p.scenario.speed for p in preps])
    n_rail = max(p.track.left_m.size for p in preps)
    rail_left = np.empty((n_batch, n_rail))
    rail_right = np.empty((n_batch, n_rail))
    for b, p in enumerate(preps):
        rail_left[b] = np.pad(p.track.left_m, (0, n_rail - p.track.left_m.size), mode="edge")
        rail_right[b] = np.pad(p.track.right_m, (0, n_rail - p.track.right_m.size), mode="edge")
    sensor_xy = np.array([p.scenario.geometry.positions_m() for p in preps])

    chunk_n = max(1, int(round(CHUNK_S * fs_hz)))
    out = np.empty((n_batch, chunk_n, n_channels))
    sos = anti_alias_sos(fs_hz * factor, fs_hz) if factor > 1 else kernel.IDENTITY_SOS
    # The filter starts in steady state for the first sample: the wagon at rest reads +g.
    g = np.array([p.model.params.gravity_mps2 for p in preps])
    zi_unit = signal.sosfilt_zi(sos)[None, :, :, None]  # (1, n_sections, 2, 1)
    zi = np.ascontiguousarray(np.broadcast_to(zi_unit * g[:, None, None, None], (n_batch, sos.shape[0], 2, n_channels)))
    remaining = np.array([p.total_n for p in preps], dtype=np.int64)  # output samples
    total = int(remaining.sum())
    pieces: list[list[NDArray[np.float64]]] = [[] for _ in preps]
    while remaining.max() > 0:
        # A chunk stops exactly at a pending fault onset; the corners change between two calls.
        n_out = np.minimum(remaining, np.where(until_onset > 0, np.minimum(until_onset, chunk_n), chunk_n))
        kernel.advance(
            q, v, slider, front_m, time_s, n_out * factor, veh, corner, speed_t, speed_v, n_speed,
            rail_left, rail_right, sensor_xy, sos, zi, factor, out,
        )  # fmt: skip
        for b in range(n_batch):
            if n_out[b]:
                pieces[b].append(out[b, : n_out[b]].copy())
        remaining -= n_out
        for b in np.flatnonzero(until_onset > 0).tolist():
            until_onset[b] -= n_out[b]
            if until_onset[b] == 0:  # the spring breaks (or the damper changes) now
                corner[b] = preps[b].model.corner_table()
        report(1.0 - remaining.sum() / total)

    results = []
    for b, p in enumerate(preps):
        accel = np.concatenate(pieces[b])[p.preroll_n : p.total_n]
        measured = p.scenario.sensor.apply(accel[:, :3], p.sensor_rng)
        if n_channels == 6:
            other = p.scenario.sensor_bogie_2 or p.scenario.sensor
            measured = np.hstack([measured, other.apply(accel[:, 3:], p.sensor_2_rng)])
        accel = measured
        results.append(
            SimulationResult(
                scenario=p.scenario,
                time_s=np.arange(p.scenario.n_samples) / fs_hz,
                accel_mps2=accel,
                model=p.model,
                final_state=State(q=q[b].copy(), v=v[b].copy(), slider=slider[b].copy()),
                derived=_derived(p),
            )
        )
    return results


def write_recording(result: SimulationResult, csv_path: str | Path) -> Path:
    """Write FILE.csv (the recording) and FILE.json (its scenario); returns the sidecar's path."""
    if result.accel_mps2.shape[1] != 3:
        raise SimulationError("a recording holds one bogie's a1..a3 for now: simulate one bogie to write it, or use the result's arrays")
    write_csv_recording(csv_path, result.time_s, result.accel_mps2)
    json_path = sidecar_path(csv_path)
    write_sidecar(json_path, result.scenario, {**result.derived, "recording": Path(csv_path).name})
    return json_path


def rerun_sidecar(json_path: str | Path, progress: Progress | None = None) -> SimulationResult:
    """Simulate again the scenario a sidecar describes: the same samples as the first time."""
    return simulate(read_sidecar(json_path), progress)
