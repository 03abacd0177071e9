"""Running model-B scenarios through model B's kernel (simulator/run.py dispatches here by Scenario.model).

Each run starts at rest (bodies.static_equilibrium) on a level stretch; the irregularities and
dips fade in over FADE_M, and the run goes SETTLE_M further before the recording's time 0 (the
pre-roll, at the profile's initial speed, at most MAX_PREROLL_S). Randomness: children of
numpy.random.SeedSequence(seed): the track, the sensors' noise and drift, the lateral acceleration,
and (a run of two bogies) bogie 2's sensors (its parts, their noise and drift, its lateral
acceleration), a child apart so that bogie 1's channels are exactly the one-bogie run's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.model_b import kernel, sensors
from bogiemon.simulator.model_b.bodies import N_DOF, State, WagonModel, build_models, static_equilibrium
from bogiemon.simulator.model_b.parameters import check_step
from bogiemon.simulator.model_b.track import generate_track, track_model
from bogiemon.simulator.result import SimulationResult
from bogiemon.simulator.scenario import MONITORED_BOGIE, Scenario, speed_table
from bogiemon.simulator.suspension import BOGIES, CORNER_ORDER
from bogiemon.simulator.track import TrackProfile

FADE_M = 25.0
SETTLE_M = 25.0
MAX_PREROLL_S = 25.0
TRACK_DS_M = 0.05
TRACK_MARGIN_M = 10.0
CHUNK_S = 2.0
MAX_TRACK_M = 400_000.0

Progress = Callable[[float], None]
FloatArray = NDArray[np.float64]


@dataclass
class _Prepared:
    scenario: Scenario
    model: WagonModel  # after the fault onset (the whole run when it is 0)
    healthy_model: WagonModel  # before it
    rest: State
    track: TrackProfile
    lateral_mps2: FloatArray  # (bogies, n) each recorded frame's, at the output rate, from the pre-roll's start
    preroll_n: int
    total_n: int
    sensor_rng: np.random.Generator
    sensors: tuple[sensors.SensorParameters, ...]  # each recorded bogie's
    sensor_2_rng: np.random.Generator | None  # bogie 2's noise and drift (two bogies)

    @property
    def onset_n(self) -> int:
        return self.preroll_n + self.scenario.onset_sample if self.scenario.fault_onset_s > 0 else 0


def preroll_s(scenario: Scenario, model: WagonModel) -> float:
    speed_mps = scenario.speed.speed_mps(0.0)
    if speed_mps <= 0.0:
        return 0.0
    distance_m = model.params.axle_offsets_m[-1] + FADE_M + SETTLE_M
    return math.ceil(min(distance_m / speed_mps, MAX_PREROLL_S) * scenario.fs_hz) / scenario.fs_hz


def _prepare(scenario: Scenario, track: TrackProfile | None) -> _Prepared:
    assert scenario.parameters is not None
    healthy, model = build_models(scenario.parameters, scenario.load, scenario.standing_faults, scenario.faults)
    if scenario.fault_onset_s == 0.0:
        healthy = model
    check_step(model.params, scenario.integration_step_s)
    # spawn(4)'s first three children are spawn(3)'s: the one-bogie streams as they always were.
    track_seed, sensor_seed, lateral_seed, bogie_2_seed = np.random.SeedSequence(scenario.seed).spawn(4)
    pre_s = preroll_s(scenario, model)
    preroll_n = int(round(pre_s * scenario.fs_hz))
    total_n = preroll_n + scenario.n_samples
    first_axle_m = model.params.axle_offsets_m[-1]
    length_m = first_axle_m + scenario.speed.speed_mps(0.0) * pre_s + scenario.speed.distance_m(scenario.duration_s) + TRACK_MARGIN_M
    if length_m > MAX_TRACK_M:
        raise SimulationError(
            f"the run covers {length_m / 1000:.0f} km of track, more than the {MAX_TRACK_M / 1000:.0f} km one run "
            "can hold: split it into shorter scenarios (e.g. consecutive seeds)"
        )
    if track is None:
        track = generate_track(
            scenario.parameters, scenario.track, length_m, np.random.default_rng(track_seed),
            ds_m=TRACK_DS_M, fade_start_m=first_axle_m + 1.0, fade_length_m=FADE_M,
        )  # fmt: skip
    elif track.length_m < length_m:
        raise ValueError(f"the given track is {track.length_m:.0f} m long, the run needs {length_m:.0f} m")
    times = (np.arange(total_n + 2) - preroll_n) / scenario.fs_hz
    lateral = [sensors.lateral_acceleration(model.params.sensor, scenario.speed, times, scenario.fs_hz, np.random.default_rng(lateral_seed))]
    parts = [model.params.sensor]
    sensor_2_rng = None
    if scenario.bogies == 2:
        part_seed, noise_seed, lateral_2_seed = bogie_2_seed.spawn(3)
        given = (scenario.parameters.get("vehicle") or {}).get("sensor_bogie_2")
        parts.append(sensors.other_part(model.params.sensor, np.random.default_rng(part_seed), given))
        check_step(dataclasses.replace(model.params, sensor=parts[1]), scenario.integration_step_s)
        lateral.append(sensors.lateral_acceleration(parts[1], scenario.speed, times, scenario.fs_hz, np.random.default_rng(lateral_2_seed)))
        sensor_2_rng = np.random.default_rng(noise_seed)
    return _Prepared(
        scenario=scenario,
        model=model,
        healthy_model=healthy,
        rest=static_equilibrium(healthy),
        track=track,
        lateral_mps2=np.array(lateral),
        preroll_n=preroll_n,
        total_n=total_n,
        sensor_rng=np.random.default_rng(sensor_seed),
        sensors=tuple(parts),
        sensor_2_rng=sensor_2_rng,
    )


def _derived(prep: _Prepared) -> dict[str, Any]:
    s, model = prep.scenario, prep.model
    rest = static_equilibrium(model)
    compression = model.corner_rows() @ rest.q
    corners = []
    for k, (corner, u) in enumerate(zip(model.corners, compression, strict=True)):
        corners.append(
            {
                "bogie": BOGIES[k // 4],
                "corner": CORNER_ORDER[k % 4].value,
                "Kz_n_per_m": corner.tangent_stiffness_n_per_m(float(u)),
                "Fs_n": corner.breakaway_n(float(u)),
                "static_compression_m": float(u),
            }
        )
    tm = track_model(s.parameters or {}, s.track)
    return {
        "model": "b",
        "integration_step_s": s.integration_step_s,
        "oversampling": s.oversampling,
        "preroll_s": prep.preroll_n / s.fs_hz,
        "n_samples": s.n_samples,
        "monitored_bogie": MONITORED_BOGIE,
        "speed_profile": s.speed.spec(),
        "faults": [f.spec() for f in s.faults],
        "corners": corners,
        "track_class": tm.track_class.name if tm.track_class else "perfect",
        "link_ratio": model.params.link_ratio,
        "contact_stiffness_n_per_m": model.params.contact_stiffness_n_per_m,
    }


def _pad(rows: list[FloatArray]) -> FloatArray:
    """Rows (or stacks of rows, the last axis the samples) padded with their last value to the longest."""
    n = max(r.shape[-1] for r in rows)
    return np.array([np.pad(r, [(0, 0)] * (r.ndim - 1) + [(0, n - r.shape[-1])], mode="edge") for r in rows])


def run_group(
    group: Sequence[Scenario], report: Progress, tracks: Sequence[TrackProfile] | None = None
) -> list[SimulationResult]:
    """Simulate scenarios of model B that share the sample rate and step; SimulationResults in order.

    `tracks` replaces the generated rail profiles (tests: identical or mirrored rails).
    """
    preps = [_prepare(s, None if tracks is None else tracks[i]) for i, s in enumerate(group)]
    n_batch = len(preps)
    fs_hz, factor = group[0].fs_hz, group[0].oversampling
    dt_s = group[0].integration_step_s
    rate_hz = fs_hz * factor
    n_channels = 3 * group[0].bogies

    q = np.array([p.rest.q for p in preps])
    v = np.array([p.rest.v for p in preps])
    w = np.array([p.rest.w for p in preps])
    front_m = np.array([p.model.params.axle_offsets_m[-1] for p in preps])
    time_s = np.array([-p.preroll_n / fs_hz for p in preps])
    veh = np.array([kernel.pack_vehicle(p.model.params, p.track.ds_m, dt_s) for p in preps])
    corner = np.array([p.healthy_model.corner_table() for p in preps])
    until_onset = np.array([p.onset_n for p in preps], dtype=np.int64)
    speed_t, speed_v, n_speed = speed_table([p.scenario.speed for p in preps])
    rail_left = _pad([p.track.left_m for p in preps])
    rail_right = _pad([p.track.right_m for p in preps])
    lateral = _pad([p.lateral_mps2 for p in preps])
    lateral_t0 = time_s.copy()
    sensor_xy = np.array([p.scenario.geometry.positions_m() for p in preps])
    cross = np.array([[c for part in p.sensors for c in part.cross_axis] for p in preps], dtype=np.float64)
    skew = np.array([np.concatenate([sensors.skew_steps(part, dt_s) for part in p.sensors]) for p in preps])
    # Bogie 2's parts are of bogie 1's type: one chain of filters per scenario.
    sos = np.array([sensors.chain_sos(p.model.params.sensor, rate_hz, fs_hz) for p in preps])
    g = np.array([p.model.params.gravity_mps2 for p in preps])
    # The chain starts in steady state for the wagon at rest: every channel reads +g.
    zi = np.ascontiguousarray(
        np.array([signal.sosfilt_zi(sos[b])[:, :, None] * np.full(n_channels, g[b])[None, None, :] for b in range(n_batch)])
    )
    line = np.ascontiguousarray(np.broadcast_to(g[:, None, None], (n_batch, n_channels, sensors.DELAY_LINE))).copy()
    line_pos = np.zeros(n_batch, dtype=np.int64)

    chunk_n = max(1, int(round(CHUNK_S * fs_hz)))
    out = np.empty((n_batch, chunk_n, n_channels))
    q_out = np.empty((n_batch, 0, N_DOF))
    remaining = np.array([p.total_n for p in preps], dtype=np.int64)
    total = int(remaining.sum())
    pieces: list[list[FloatArray]] = [[] for _ in preps]
    while remaining.max() > 0:
        n_out = np.minimum(remaining, np.where(until_onset > 0, np.minimum(until_onset, chunk_n), chunk_n))
        kernel.advance(
            q, v, w, front_m, time_s, n_out * factor, veh, corner, speed_t, speed_v, n_speed, rail_left, rail_right,
            lateral, lateral_t0, fs_hz, sensor_xy, cross, skew, sos, zi, line, line_pos, factor, out, q_out,
        )  # fmt: skip
        for b in range(n_batch):
            if n_out[b]:
                pieces[b].append(out[b, : n_out[b]].copy())
        remaining -= n_out
        for b in np.flatnonzero(until_onset > 0).tolist():
            until_onset[b] -= n_out[b]
            if until_onset[b] == 0:  # the fault appears now
                corner[b] = preps[b].model.corner_table()
        report(1.0 - remaining.sum() / total)

    results = []
    for b, p in enumerate(preps):
        chain = np.concatenate(pieces[b])[p.preroll_n : p.total_n]
        accel = sensors.convert(chain[:, :3], p.model.params.sensor, fs_hz, p.sensor_rng)
        # The scenario's own sensor errors (model A's vocabulary) apply on top, so that a plan's
        # per-wagon sensor errors mean the same on both models.
        accel = p.scenario.sensor.apply(accel, p.sensor_rng)
        if n_channels == 6:
            assert p.sensor_2_rng is not None
            other = sensors.convert(chain[:, 3:], p.sensors[1], fs_hz, p.sensor_2_rng)
            accel = np.hstack([accel, p.scenario.sensor.apply(other, p.sensor_2_rng)])
        results.append(
            SimulationResult(
                scenario=p.scenario,
                time_s=np.arange(p.scenario.n_samples) / fs_hz,
                accel_mps2=accel,
                model=p.model,
                final_state=State(q=q[b].copy(), v=v[b].copy(), w=w[b].copy()),
                derived=_derived(p),
            )
        )
    return results


def integrate(
    model: WagonModel,
    state: State,
    duration_s: float,
    step_s: float = 2.5e-4,
    record_every: int = 8,
    track: TrackProfile | None = None,
    speed_kmh: float = 0.0,
) -> tuple[FloatArray, FloatArray, State]:
    """Advance one wagon from `state` (free decay, checks): (times (n,), positions (n, 25), final state).

    No sensor errors; a level track unless one is given; positions every `record_every` steps.
    """
    n_out = int(round(duration_s / (step_s * record_every)))
    if track is None:
        track = TrackProfile(ds_m=TRACK_DS_M, left_m=np.zeros(4), right_m=np.zeros(4))
    speed = speed_kmh / 3.6
    q, v, w = state.q[None].copy(), state.v[None].copy(), state.w[None].copy()
    front = np.array([model.params.axle_offsets_m[-1]])
    time_s = np.zeros(1)
    ident = np.tile(sensors.IDENTITY_SECTION, (1, 3, 1))
    out = np.empty((1, n_out, 3))
    q_out = np.empty((1, n_out, N_DOF))
    kernel.advance(
        q, v, w, front, time_s, np.array([n_out * record_every]), kernel.pack_vehicle(model.params, track.ds_m, step_s)[None],
        model.corner_table()[None], np.zeros((1, 1)), np.full((1, 1), speed), np.ones(1, dtype=np.int64),
        track.left_m[None], track.right_m[None], np.zeros((1, 1, 2)), np.zeros(1), 1.0, np.zeros((1, 3, 2)),
        np.zeros((1, 3)), np.zeros((1, 3)), ident, np.zeros((1, 3, 2, 3)), np.zeros((1, 3, sensors.DELAY_LINE)),
        np.zeros(1, dtype=np.int64), record_every, out, q_out,
    )  # fmt: skip
    times = (np.arange(n_out) * step_s * record_every).astype(np.float64, copy=False)
    return times, q_out[0], State(q=q[0], v=v[0], w=w[0])
