"""The sensor parts (simulator/sensors.py SENSOR_VARIANTS): the standard part bit for bit as before,
each part's filter as designed, its noise where it enters, on model A and model B."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.model_b import sensors as b_sensors
from bogiemon.simulator.model_b.parameters import (
    MAX_ANTIALIAS_ORDER, default_parameter_set, wagon_parameters, with_ideal_sensor, with_sensor_variant,
)  # fmt: skip
from bogiemon.simulator.model_b.sensors import bias_drift
from bogiemon.simulator.run import simulate, simulate_batch
from bogiemon.simulator.scenario import Scenario
from bogiemon.simulator.sensors import SENSOR_VARIANTS, SensorModel

FS_HZ = 500.0
FILTERED = [name for name, part in SENSOR_VARIANTS.items() if part.order]
B_PARAMS = default_parameter_set()


def reference_apply(accel: np.ndarray, sensor: SensorModel, rng: np.random.Generator) -> np.ndarray:
    """SensorModel.apply as it was before the parts existed, written out."""
    out = accel if sensor.gain == (1.0, 1.0, 1.0) else accel * np.asarray(sensor.gain)
    out = out + np.asarray(sensor.bias_mps2)
    if sensor.noise_mps2 > 0:
        out = out + sensor.noise_mps2 * rng.standard_normal(out.shape)
    if sensor.quantum_mps2 > 0:
        out = sensor.quantum_mps2 * np.round(out / sensor.quantum_mps2)
    return out


def butterworth_power(f_hz: np.ndarray, order: int, corner_hz: float, fs_hz: float = FS_HZ) -> np.ndarray:
    """|H|^2 of a digital (bilinear) Butterworth low-pass: 1 / (1 + (tan(pi f / fs) / tan(pi fc / fs))^(2 order))."""
    ratio = np.tan(np.pi * np.asarray(f_hz) / fs_hz) / math.tan(math.pi * corner_hz / fs_hz)
    return 1.0 / (1.0 + ratio ** (2 * order))


def amplitude(x: np.ndarray, f_hz: float) -> float:
    """The amplitude of the sine at f_hz in x (a lock-in: its projection on sine and cosine)."""
    t = np.arange(x.size) / FS_HZ
    return float(2.0 * np.hypot(np.mean(x * np.sin(2 * np.pi * f_hz * t)), np.mean(x * np.cos(2 * np.pi * f_hz * t))))


# --- the standard part: what the sensor always reported ---------------------------------------------


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    noise=st.sampled_from([0.0, 0.01, 0.4]),
    quantum=st.sampled_from([0.0, 0.0048]),
    gain=st.sampled_from([(1.0, 1.0, 1.0), (1.02, -1.0, 0.97)]),
)
def test_the_standard_part_reports_bit_for_bit_what_the_sensor_always_reported(seed: int, noise: float, quantum: float, gain) -> None:
    accel = 9.81 + np.random.default_rng(seed).standard_normal((2000, 3))
    sensor = SensorModel(noise_mps2=noise, bias_mps2=(0.1, -0.2, 0.3), quantum_mps2=quantum, gain=gain)
    ours = sensor.apply(accel, np.random.default_rng([seed, 1]))
    np.testing.assert_array_equal(ours, reference_apply(accel, sensor, np.random.default_rng([seed, 1])))


def test_a_sidecar_written_before_the_parts_reads_as_the_standard_part() -> None:
    data = Scenario(duration_s=2.0).to_dict()
    assert data["sensor"]["variant"] == "standard" and data["sensor"]["element_noise_mps2"] == [0.0, 0.0, 0.0]
    del data["sensor"]["variant"], data["sensor"]["element_noise_mps2"]
    assert Scenario.from_dict(data).sensor == SensorModel()


def test_a_sidecar_keeps_the_part_and_the_element_noise() -> None:
    scenario = Scenario(duration_s=2.0, sensor=SensorModel(noise_mps2=0.01, variant="mems-odr10", element_noise_mps2=(0.0, 0.4, 0.0)))
    assert Scenario.from_dict(scenario.to_dict()) == scenario


def test_an_unknown_part_or_a_part_in_model_bs_sensor_model_is_refused() -> None:
    with pytest.raises(SimulationError, match="unknown sensor variant 'piezo'"):
        Scenario(sensor=SensorModel(variant="piezo"))
    with pytest.raises(SimulationError, match="with_sensor_variant"):
        Scenario(model="b", sensor=SensorModel(variant="mems-odr10"))
    with pytest.raises(SimulationError, match="element noise"):
        Scenario(sensor=SensorModel(element_noise_mps2=(0.0, -0.1, 0.0)))


def reference_chain_sos(sensor, rate_hz: float, fs_out_hz: float) -> np.ndarray:
    """Model B's chain before the parts existed: its resonance, then a 4th-order Butterworth."""
    butter = signal.butter(4, sensor.antialias_fraction_of_fs * fs_out_hz, fs=rate_hz, output="sos")
    return np.vstack([b_sensors.resonance_section(sensor.resonance_hz, sensor.resonance_damping_ratio, rate_hz)[None, :], butter])


def reference_convert(accel: np.ndarray, sensor, fs_hz: float, rng: np.random.Generator) -> np.ndarray:
    """Model B's converter before the parts existed, written out."""
    out = accel * np.array(sensor.gain) + np.array(sensor.bias_mps2) + bias_drift(sensor, accel.shape[0], fs_hz, rng)
    white = sensor.noise_density_mps2_per_sqrt_hz * math.sqrt(fs_hz / 2.0) * rng.standard_normal(accel.shape)
    out = out + signal.sosfilt(signal.butter(4, sensor.antialias_fraction_of_fs * fs_hz, fs=fs_hz, output="sos"), white, axis=0)
    lsb = 2.0 * sensor.range_g * 9.80665 / 2**sensor.bits
    return np.clip(np.round(out / lsb), -(2 ** (sensor.bits - 1)), 2 ** (sensor.bits - 1) - 1) * lsb


def test_model_bs_shipped_sensor_keeps_its_chain_and_converter_bit_for_bit() -> None:
    sensor = wagon_parameters(B_PARAMS, "full").sensor
    assert (sensor.antialias_order, sensor.noise_inside, sensor.element_noise_density_mps2_per_sqrt_hz) == (4, True, (0.0, 0.0, 0.0))
    assert "antialias_order" not in B_PARAMS["vehicle"]["sensor"]  # the shipped file, as it was
    np.testing.assert_array_equal(b_sensors.chain_sos(sensor, 4000.0, FS_HZ), reference_chain_sos(sensor, 4000.0, FS_HZ))
    accel = 9.81 + np.random.default_rng(3).standard_normal((5000, 3))
    np.testing.assert_array_equal(
        b_sensors.convert(accel, sensor, FS_HZ, np.random.default_rng(4)), reference_convert(accel, sensor, FS_HZ, np.random.default_rng(4))
    )
    assert with_sensor_variant(B_PARAMS, "standard") == B_PARAMS


# --- each part's filter, as designed ------------------------------------------------------------------


@pytest.mark.parametrize("name", FILTERED)
def test_a_parts_filter_has_its_designed_magnitude_at_a_few_frequencies(name: str) -> None:
    part = SENSOR_VARIANTS[name]
    corner_hz = part.corner_fraction_of_fs * FS_HZ
    n = 20_000
    t = np.arange(n) / FS_HZ
    for f_hz in (2.0, 0.5 * corner_hz, corner_hz, 1.5 * corner_hz, 200.0):
        f_hz = round(f_hz * n / FS_HZ) * FS_HZ / n  # a whole number of periods in the record
        sine = np.sin(2 * np.pi * f_hz * t)
        out = SensorModel(variant=name).apply(np.column_stack([sine] * 3), np.random.default_rng(0))
        measured = amplitude(out[n // 2 :, 0], f_hz)  # past the filter's start
        expected = math.sqrt(butterworth_power(np.array(f_hz), part.order, corner_hz))
        assert measured == pytest.approx(expected, rel=1e-3, abs=1e-9), f_hz
        assert abs(part.response(np.array([f_hz / FS_HZ]))[0]) == pytest.approx(expected, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("name", list(SENSOR_VARIANTS))
def test_a_part_passes_gravity_with_gain_one_from_its_first_sample(name: str) -> None:
    out = SensorModel(variant=name).apply(np.full((5000, 3), 9.81), np.random.default_rng(0))
    np.testing.assert_allclose(out, 9.81, rtol=1e-12)
    assert abs(SENSOR_VARIANTS[name].response(np.array([0.0]))[0]) == pytest.approx(1.0, rel=1e-12)


def welch_density(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return signal.welch(x, fs=FS_HZ, nperseg=1024)


@pytest.mark.parametrize("name", FILTERED)
def test_the_element_noise_has_the_hiss_density_shaped_by_the_parts_filter_on_its_channel_alone(name: str) -> None:
    part = SENSOR_VARIANTS[name]
    out = SensorModel(variant=name, element_noise_mps2=(0.0, 0.4, 0.0)).apply(np.zeros((400_000, 3)), np.random.default_rng(5))
    assert np.all(out[:, [0, 2]] == 0.0)
    f, psd = welch_density(out[:, 1])
    density = 0.4**2 / (FS_HZ / 2)  # white noise of 0.4 m/s^2 per sample at 500 Hz, one-sided
    for f_hz in (5.0, part.corner_fraction_of_fs * FS_HZ, 1.5 * part.corner_fraction_of_fs * FS_HZ):
        k = int(np.argmin(np.abs(f - f_hz)))
        band = slice(k - 3, k + 4)
        expected = density * np.mean(butterworth_power(f[band], part.order, part.corner_fraction_of_fs * FS_HZ))
        assert np.mean(psd[band]) == pytest.approx(expected, rel=0.1), f_hz


@pytest.mark.parametrize("name", FILTERED)
def test_a_parts_own_noise_enters_before_or_after_its_filter_as_it_says(name: str) -> None:
    part = SENSOR_VARIANTS[name]
    out = SensorModel(noise_mps2=0.03, variant=name).apply(np.zeros((400_000, 3)), np.random.default_rng(6))
    f, psd = welch_density(out[:, 0])
    density = 0.03**2 / (FS_HZ / 2)
    top = (f > 190.0) & (f < 240.0)
    shaped = density * np.mean(butterworth_power(f[top], part.order, part.corner_fraction_of_fs * FS_HZ))
    assert np.mean(psd[top]) == pytest.approx(shaped if part.noise_inside else density, rel=0.1)


# --- model B: the part is its own chain ----------------------------------------------------------------


@pytest.mark.parametrize("name", FILTERED)
def test_model_b_takes_the_parts_filter_as_its_anti_alias_and_its_noise_entry(name: str) -> None:
    part = SENSOR_VARIANTS[name]
    sensor = wagon_parameters(with_sensor_variant(B_PARAMS, name), "tare").sensor
    assert (sensor.antialias_order, sensor.antialias_fraction_of_fs, sensor.noise_inside) == (part.order, part.corner_fraction_of_fs, part.noise_inside)
    chain = b_sensors.chain_sos(sensor, 4000.0, FS_HZ)
    assert chain.shape == (b_sensors.N_SECTIONS, 6) and b_sensors.N_SECTIONS == 1 + (MAX_ANTIALIAS_ORDER + 1) // 2
    f_hz = np.array([1.0, 20.0, 50.0, 125.0, 200.0])
    resonance = b_sensors.resonance_section(sensor.resonance_hz, sensor.resonance_damping_ratio, 4000.0)[None, :]
    _, h_chain = signal.sosfreqz(chain, worN=f_hz, fs=4000.0)
    _, h_resonance = signal.sosfreqz(resonance, worN=f_hz, fs=4000.0)
    expected = butterworth_power(f_hz, part.order, part.corner_fraction_of_fs * FS_HZ, fs_hz=4000.0)
    np.testing.assert_allclose(np.abs(h_chain / h_resonance) ** 2, expected, rtol=1e-9, atol=1e-15)


def test_model_bs_noise_after_its_filter_is_white_and_its_element_noise_inside_is_shaped() -> None:
    ideal = wagon_parameters(with_sensor_variant(with_ideal_sensor(B_PARAMS), "two-pole"), "full").sensor
    after = type(ideal)(**{**ideal.__dict__, "noise_density_mps2_per_sqrt_hz": 1e-3})
    f, psd = welch_density(b_sensors.convert(np.zeros((400_000, 3)), after, FS_HZ, np.random.default_rng(7))[:, 0])
    assert np.mean(psd[f > 190.0]) == pytest.approx(1e-6, rel=0.1)  # white up to Nyquist
    inside = type(ideal)(**{**ideal.__dict__, "element_noise_density_mps2_per_sqrt_hz": (0.0, 0.0, 1e-3)})
    out = b_sensors.convert(np.zeros((400_000, 3)), inside, FS_HZ, np.random.default_rng(8))
    assert np.all(out[:, :2] == 0.0)
    f, psd = welch_density(out[:, 2])
    top = (f > 190.0) & (f < 240.0)
    assert np.mean(psd[top]) == pytest.approx(1e-6 * np.mean(butterworth_power(f[top], 2, 125.0)), rel=0.1)


def test_model_b_parts_of_other_orders_share_a_batch_each_as_alone() -> None:
    scenarios = [
        Scenario(model="b", duration_s=4.0, seed=1, parameters=with_sensor_variant(B_PARAMS, name)) for name in ("standard", "two-pole", "mems-odr10")
    ]
    together = simulate_batch(scenarios)
    for scenario, result in zip(scenarios, together, strict=True):
        np.testing.assert_array_equal(result.accel_mps2, simulate(scenario).accel_mps2)
    assert not np.array_equal(together[0].accel_mps2, together[1].accel_mps2)
