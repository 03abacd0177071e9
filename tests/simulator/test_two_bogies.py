"""Both bogies recorded (Scenario.bogies = 2): a1..a3 on bogie 1 (leading), b1..b3 on bogie 2 at
the same named corners of its own frame; one-bogie runs exactly as before; the physics between them."""

import copy
import dataclasses
import hashlib
import json

import numpy as np
import pytest
from scipy import signal

from bogiemon.detection import BogieGeometry, IndicatorStream, ProcessingSettings
from bogiemon.detection.features import WindowFeatures
from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.model_b import bodies as model_b_bodies
from bogiemon.simulator.model_b.parameters import default_parameter_set as model_b_parameter_set
from bogiemon.simulator.model_b.parameters import with_ideal_sensor
from bogiemon.simulator.params import centre_offset_m, default_parameter_set
from bogiemon.simulator.run import simulate, simulate_batch, write_recording
from bogiemon.simulator.scenario import Scenario, SpeedProfile
from bogiemon.simulator.sensors import SensorModel
from bogiemon.simulator.suspension import parse_fault
from bogiemon.simulator import vehicle
from bogiemon.detection import Corner

TRACKS = ("erri-low", "erri-high", "fra-4", "fra-5", "fra-6")
# Digests of two short runs' samples as the simulator gave them before it could record two bogies
# (commit fef8356): a one-bogie run must stay bit for bit what it was.
GOLDEN = {
    "a": "58527c1debc251d8218c5ced91b5cccc4af0418ae27677d9dbe26d66ecc6ab15",
    "b": "2237f539b418b22157f66e968222ad2be4dbbec605be8cfd16a6b31e908ec7f8",
}


def _golden_scenarios() -> list[Scenario]:
    return [
        Scenario(
            seed=7, duration_s=3.0, speed=SpeedProfile(((0, 70), (3, 90))), track="fra-4",
            faults=(parse_fault("type_a:rear_outer:0.0@leading-left"),),
            sensor=SensorModel(noise_mps2=0.02, bias_mps2=(0.1, -0.1, 0.05), gain=(1.01, 0.99, 1.0), quantum_mps2=0.004),
        ),
        Scenario(seed=8, duration_s=3.0, load="tare", model="b", faults=(parse_fault("type_b::0.5@trailing-bogie:trailing-right"),), fault_onset_s=1.0),
    ]  # fmt: skip


def test_a_one_bogie_run_gives_the_samples_it_gave_before_two_bogies_existed() -> None:
    for result in simulate_batch(_golden_scenarios()):
        assert result.accel_mps2.shape == (1500, 3)
        assert hashlib.sha256(np.ascontiguousarray(result.accel_mps2).tobytes()).hexdigest() == GOLDEN[result.scenario.model]


def test_bogie_1_of_a_two_bogie_run_is_exactly_the_one_bogie_run_and_bogie_2_another_frame() -> None:
    scenarios = _golden_scenarios()
    one = simulate_batch(scenarios)
    both = simulate_batch([dataclasses.replace(s, bogies=2) for s in scenarios])
    for alone, pair in zip(one, both, strict=True):
        assert pair.accel_mps2.shape == (1500, 6)
        np.testing.assert_array_equal(pair.accel_mps2[:, :3], alone.accel_mps2)
        assert np.std(pair.accel_mps2[:, 3:] - pair.accel_mps2[:, :3]) > 0.1


def test_a_mixed_batch_gives_each_scenario_what_it_gives_alone() -> None:
    scenarios = [Scenario(seed=1, duration_s=2.0), Scenario(seed=1, duration_s=2.0, bogies=2), Scenario(seed=2, duration_s=2.0, model="b", bogies=2)]
    batch = simulate_batch(scenarios)
    for scenario, result in zip(scenarios, batch, strict=True):
        np.testing.assert_array_equal(simulate(scenario).accel_mps2, result.accel_mps2)


@pytest.mark.parametrize(
    ("spec", "bogie"),
    [("type_a:rear_outer:0.0@2:leading-left", "trailing"), ("type_a:rear_outer:0.0@1:leading-left", "leading"),
     ("type_a:rear_outer:0.0@leading-left", "leading"), ("type_a:rear_outer:0.0@trailing-bogie:leading-left", "trailing")],
)  # fmt: skip
def test_a_fault_names_its_bogie_by_number_the_older_names_still_read(spec: str, bogie: str) -> None:
    fault = parse_fault(spec)
    assert (fault.bogie, fault.corner) == (bogie, Corner.LEADING_LEFT)
    assert fault.bogie_number == (2 if bogie == "trailing" else 1)
    assert fault.spec() == ("type_a:rear_outer:0.0@2:leading-left" if bogie == "trailing" else "type_a:rear_outer:0.0@leading-left")


def test_an_unknown_bogie_number_is_one_clear_error() -> None:
    with pytest.raises(SimulationError, match=r"unknown bogie '3': use 1 or 2"):
        parse_fault("type_a:rear_outer:0.0@3:leading-left")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [(dict(bogies=3), "bogies recorded must be 1 or 2"), (dict(bogies=True), "bogies recorded must be 1 or 2"),
     (dict(sensor_bogie_2=SensorModel()), "give it with bogies=2 on model a"),
     (dict(bogies=2, model="b", sensor_bogie_2=SensorModel()), "give it with bogies=2 on model a")],
)  # fmt: skip
def test_a_bad_number_of_bogies_is_one_clear_error(kwargs, message: str) -> None:
    with pytest.raises(SimulationError, match=message):
        Scenario(**kwargs)


def test_a_two_bogie_scenario_survives_its_sidecar_dict_and_a_one_bogie_dict_is_unchanged() -> None:
    scenario = Scenario(bogies=2, sensor_bogie_2=SensorModel(noise_mps2=0.01, gain=(1.02, 1.0, 0.98)), faults=(parse_fault("type_b::0.5@2:trailing-right"),))
    assert Scenario.from_dict(json.loads(json.dumps(scenario.to_dict()))) == scenario
    assert "bogies" not in Scenario().to_dict() and Scenario.from_dict(Scenario().to_dict()).bogies == 1


def test_a_recording_of_two_bogies_is_refused_in_one_line_until_the_format_holds_them(tmp_path) -> None:
    result = simulate(Scenario(duration_s=1.0, bogies=2))
    with pytest.raises(SimulationError, match="a recording holds one bogie"):
        write_recording(result, tmp_path / "run.csv")


def test_model_a_bogie_2_reads_through_its_own_sensor_errors() -> None:
    ideal = simulate(Scenario(duration_s=2.0, bogies=2)).accel_mps2
    gained = simulate(Scenario(duration_s=2.0, bogies=2, sensor_bogie_2=SensorModel(gain=(2.0, 1.0, 1.0)))).accel_mps2
    np.testing.assert_array_equal(gained[:, :5], np.c_[ideal[:, :3], 2.0 * ideal[:, 3], ideal[:, 4]])


def test_model_b_bogie_2_has_other_parts_unless_its_table_states_them() -> None:
    def at_rest(parameters: dict) -> np.ndarray:
        """Each channel's mean over 2 s standing on a perfect track: its gain x g plus its bias."""
        scenario = Scenario(duration_s=2.0, model="b", bogies=2, track="perfect", speed=SpeedProfile.constant(0.0), parameters=parameters)
        return simulate(scenario).accel_mps2.mean(axis=0)

    drawn = at_rest(model_b_parameter_set())
    assert np.max(np.abs(drawn[3:] - drawn[:3])) > 0.05
    stated = copy.deepcopy(model_b_parameter_set())
    stated["vehicle"]["sensor_bogie_2"] = {k: stated["vehicle"]["sensor"][k] for k in ("gain", "bias_mps2", "cross_axis", "skew_s")}
    same = at_rest(stated)
    assert np.max(np.abs(same[3:] - same[:3])) < 0.01  # the same errors, the noise and drift (2 mg) drawn apart
    np.testing.assert_allclose(at_rest(with_ideal_sensor(model_b_parameter_set())), 9.81, atol=0.01)


@pytest.mark.parametrize("model", ["a", "b"])
def test_a_wagon_loaded_60_40_rests_with_60_percent_of_its_carbody_on_the_leading_bogie(model: str) -> None:
    params = copy.deepcopy(default_parameter_set() if model == "a" else model_b_parameter_set())
    body = params["vehicle"]["carbody"]
    body["centre_of_mass_offset_m"] = centre_offset_m(0.6, float(body["bogie_centre_distance_m"]))
    if model == "a":
        wagon = vehicle.build_model(params, "full")
        rest = vehicle.static_equilibrium(wagon)
        bowl_n = wagon.params.bowl_stiffness_n_per_m * (wagon.bowl_rows() @ rest.q)
        bearer_n = wagon.params.side_bearer_stiffness_n_per_m * (wagon.side_bearer_rows() @ rest.q)
        carried = bowl_n + bearer_n.reshape(2, 2).sum(axis=1)
        weight_n = wagon.params.carbody_mass_kg * wagon.params.gravity_mps2
    else:
        wagon_b = model_b_bodies.build_model(params, "full")
        rest_b = model_b_bodies.static_equilibrium(wagon_b)
        _, _, element = model_b_bodies.forces_reference(wagon_b, rest_b.q, rest_b.v, rest_b.w, np.zeros(8), np.zeros(8), 2.5e-4)
        carried = np.asarray(element.bowl_n) + np.asarray(element.bearer_n).reshape(2, 2).sum(axis=1)
        weight_n = wagon_b.params.carbody_mass_kg * wagon_b.params.gravity_mps2
    np.testing.assert_allclose(carried / weight_n, [0.6, 0.4], atol=1e-6)


# --- the physics between the bogies -----------------------------------------------------------------


def _features(accel: np.ndarray) -> np.ndarray:
    """(2, n_windows, 14) per bogie: the ten couplings and I1n..I4n of each 120 s window."""
    settings, geometry = ProcessingSettings(), BogieGeometry()
    out = []
    for k in range(2):
        windows = IndicatorStream(settings, geometry).process(accel[:, 3 * k : 3 * k + 3])
        out.append([np.r_[WindowFeatures(w.spectra, geometry).coupling, w.normalised] for w in windows if w.spectra is not None])
    return np.array(out)


@pytest.mark.parametrize("model", ["a", "b"])
def test_on_a_symmetric_healthy_wagon_the_two_bogies_features_have_one_distribution(model: str) -> None:
    """Eight runs of the nominal wagon (exact sensors) over every track quality at 50-106 km/h: per
    feature, the bogies' run means differ by less than 4 standard errors of their difference, and
    their spread across runs by less than a factor 2.5."""
    parameters = None if model == "a" else with_ideal_sensor(model_b_parameter_set())
    scenarios = [
        Scenario(seed=s, duration_s=130.0, model=model, bogies=2, track=TRACKS[s % 5], speed=SpeedProfile.constant(50 + 8 * s), parameters=parameters)
        for s in range(8)
    ]  # fmt: skip
    means = np.array([_features(r.accel_mps2).mean(axis=1) for r in simulate_batch(scenarios)])  # (runs, 2, 14)
    diff = means[:, 1] - means[:, 0]
    z = diff.mean(axis=0) / (diff.std(axis=0, ddof=1) / np.sqrt(len(diff)))
    assert np.all(np.abs(z) < 4.0), np.round(z, 1)
    ratio = means[:, 1].std(axis=0) / means[:, 0].std(axis=0)
    assert np.all((ratio > 1 / 2.5) & (ratio < 2.5)), np.round(ratio, 2)


@pytest.mark.parametrize("model", ["a", "b"])
def test_bogie_2_meets_the_track_later_by_the_bogie_distance_over_the_speed(model: str) -> None:
    speed_kmh = 72.0
    result = simulate(Scenario(seed=3, duration_s=40.0, model=model, bogies=2, speed=SpeedProfile.constant(speed_kmh)))
    p = result.model.params
    distance_m = p.bogie_centre_distance_m if model == "a" else 2.0 * p.half_bogie_distance_m
    fs_hz = result.scenario.fs_hz
    # 2-30 Hz: the track's input through the primary springs, above the carbody's common modes.
    sos = signal.butter(4, [2.0, 30.0], "bandpass", fs=fs_hz, output="sos")
    a1, b1 = (signal.sosfilt(sos, result.accel_mps2[:, k]) for k in (0, 3))
    corr = signal.correlate(b1, a1, mode="full")
    lags_s = np.arange(-a1.size + 1, a1.size) / fs_hz
    near = np.abs(lags_s) < 3.0
    assert lags_s[near][np.argmax(corr[near])] == pytest.approx(distance_m / (speed_kmh / 3.6), abs=1.5 / fs_hz)


@pytest.mark.parametrize("model", ["a", "b"])
def test_a_broken_spring_on_bogie_2_couples_bogie_2s_modes_not_bogie_1s(model: str) -> None:
    base = Scenario(seed=4, duration_s=130.0, model=model, bogies=2, track="erri-low", speed=SpeedProfile.constant(70.0))
    healthy, broken = simulate_batch([base, dataclasses.replace(base, faults=(parse_fault("type_a:rear_outer:0.0@2:leading-left"),))])
    shift = _features(broken.accel_mps2)[:, :, :10].mean(axis=1) - _features(healthy.accel_mps2)[:, :, :10].mean(axis=1)
    moved = np.linalg.norm(shift, axis=1)  # per bogie, of the couplings
    assert moved[1] > 0.4 and moved[0] < 0.15 * moved[1], moved
