"""Scenarios, sensors, recordings with their sidecars, batches, and `bogiemon simulate`."""

import io
import json
import subprocess
import sys
from typing import Any
from pathlib import Path

import numpy as np
import pytest

import bogiemon
from bogiemon.cli.main import main
from bogiemon.detection import BogieGeometry, Corner
from bogiemon.drivers.recording import read_csv_recording, write_csv_recording
from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.run import rerun_sidecar, simulate, simulate_batch, write_recording
from bogiemon.simulator.scenario import Scenario, SpeedProfile, read_sidecar
from bogiemon.simulator.sensors import Decimator, SensorModel
from bogiemon.simulator.suspension import parse_fault

BOGIEMON = [sys.executable, "-m", "bogiemon.cli.main"]


def test_the_default_scenario_is_a_healthy_full_load_run() -> None:
    s = Scenario()
    assert (s.load, s.speed.spec(), s.track, s.duration_s, s.seed, s.faults) == ("full", "0:80", "erri-low", 120.0, 0, ())
    assert (s.fs_hz, s.oversampling, s.integration_step_s) == (500.0, 8, 2.5e-4)
    assert s.geometry == BogieGeometry()


def test_the_integration_step_is_a_whole_fraction_of_the_sample_period() -> None:
    assert Scenario(fs_hz=1000.0).oversampling == 4
    assert Scenario(fs_hz=300.0).integration_step_s == pytest.approx(1 / 4200)  # 14 steps, <= 0.25 ms


def test_a_sidecar_reproduces_the_recording_exactly(tmp_path: Path) -> None:
    scenario = Scenario(
        load="tare",
        speed=SpeedProfile.parse("0:40,10:70"),
        track="fra-5",
        duration_s=12.0,
        seed=42,
        faults=(
            parse_fault("type_a:front_outer:0.5@trailing-left"),
            parse_fault("custom:9e5:3e3@trailing-bogie:leading-right"),
        ),
        fs_hz=400.0,
        geometry=BogieGeometry(
            sensor_spacing_m=1.9, corners=(Corner.TRAILING_RIGHT, Corner.TRAILING_LEFT, Corner.LEADING_RIGHT)
        ),
        sensor=SensorModel(noise_mps2=0.05, bias_mps2=(0.1, -0.2, 0.0), quantum_mps2=0.001),
    )
    result = simulate(scenario)
    sidecar = write_recording(result, tmp_path / "run.csv")
    assert sidecar == tmp_path / "run.json"
    document = json.loads(sidecar.read_text())
    assert document["bogiemon_version"] == bogiemon.__version__ and document["monitored_bogie"] == "leading"
    assert document["derived"]["faults"] == [f.spec() for f in scenario.faults]
    assert document["derived"]["integration_step_s"] == 2.5e-4  # 10 steps per 2.5 ms sample
    assert read_sidecar(sidecar) == scenario
    again = rerun_sidecar(sidecar)
    np.testing.assert_array_equal(again.accel_mps2, result.accel_mps2)
    recording = read_csv_recording(tmp_path / "run.csv")
    assert recording.fs_hz == pytest.approx(400.0)
    np.testing.assert_allclose(recording.accel_mps2, result.accel_mps2, atol=5e-7)


def test_the_sidecar_keeps_every_parameter_so_a_changed_parameter_set_is_reproduced(tmp_path: Path) -> None:
    params = Scenario().parameters
    params = json.loads(json.dumps(params))
    params["vehicle"]["primary"]["stick_stiffness_n_per_m"] = 1e7
    scenario = Scenario(duration_s=3.0, parameters=params)
    result = simulate(scenario)
    write_recording(result, tmp_path / "r.csv")
    np.testing.assert_array_equal(rerun_sidecar(tmp_path / "r.json").accel_mps2, result.accel_mps2)
    assert not np.array_equal(simulate(Scenario(duration_s=3.0)).accel_mps2, result.accel_mps2)


def test_a_batch_gives_each_scenario_what_it_gives_alone() -> None:
    scenarios = [
        Scenario(duration_s=6.0, seed=1),
        Scenario(duration_s=4.0, seed=2, load="tare", speed=SpeedProfile.constant(30.0)),
        Scenario(duration_s=5.0, seed=3, fs_hz=250.0, faults=(parse_fault("type_b::0.5@leading-right"),)),
        Scenario(duration_s=6.0, seed=1, track="fra-4"),
    ]
    fractions: list[float] = []
    batch = simulate_batch(scenarios, fractions.append)
    for scenario, result in zip(scenarios, batch, strict=True):
        assert result.scenario == scenario
        np.testing.assert_array_equal(result.accel_mps2, simulate(scenario).accel_mps2)
    assert fractions == sorted(fractions) and fractions[-1] == pytest.approx(1.0)


def test_the_speed_profile_is_piecewise_linear_and_held_after_its_end() -> None:
    profile = SpeedProfile.parse("0:60, 120:100")
    assert profile.speed_mps(60.0) == pytest.approx(80 / 3.6)
    assert profile.speed_mps(500.0) == pytest.approx(100 / 3.6)
    assert profile.distance_m(120.0) == pytest.approx(80 / 3.6 * 120)
    assert profile.distance_m(180.0) == pytest.approx(80 / 3.6 * 120 + 100 / 3.6 * 60)


def test_a_faster_run_shakes_the_bogie_more() -> None:
    slow, fast = simulate_batch([Scenario(duration_s=20.0, speed=SpeedProfile.constant(s)) for s in (40.0, 110.0)])
    assert fast.accel_mps2.std() > 1.5 * slow.accel_mps2.std()


def test_standing_still_the_sensors_read_gravity() -> None:
    result = simulate(Scenario(duration_s=2.0, speed=SpeedProfile.constant(0.0), track="erri-high"))
    np.testing.assert_allclose(result.accel_mps2, 9.81, atol=1e-9)


def test_the_decimator_removes_what_would_alias_and_keeps_the_band() -> None:
    fs_in, factor = 4000.0, 8
    t = np.arange(40000) / fs_in
    decimator = Decimator(fs_in, factor, 2)
    x = np.column_stack([np.sin(2 * np.pi * 20.0 * t), np.sin(2 * np.pi * 480.0 * t)])  # 480 Hz folds to 20 Hz
    y = np.concatenate([decimator.process(x[i : i + 4000]) for i in range(0, 40000, 4000)])
    assert y.shape == (5000, 2)
    assert np.std(y[1000:, 0]) == pytest.approx(np.sqrt(0.5), rel=1e-3)
    assert np.std(y[1000:, 1]) < 1e-4 * np.sqrt(0.5)


def test_sensor_errors_are_bias_noise_and_quantisation() -> None:
    ideal = np.full((20000, 3), 9.81)
    model = SensorModel(noise_mps2=0.02, bias_mps2=(0.5, 0.0, -0.5), quantum_mps2=0.01)
    out = model.apply(ideal, np.random.default_rng(0))
    np.testing.assert_allclose(out.mean(axis=0), [10.31, 9.81, 9.31], atol=1e-3)
    np.testing.assert_allclose(out.std(axis=0), np.sqrt(0.02**2 + 0.01**2 / 12), rtol=0.05)
    np.testing.assert_allclose(out / 0.01, np.round(out / 0.01), atol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"track": "bumpy"}, "unknown track 'bumpy'"),
        ({"load": "half"}, "unknown load 'half'"),
        ({"duration_s": -1.0}, "duration must be positive"),
        ({"fs_hz": 0.0}, "sample rate must be positive"),
        ({"seed": -3}, "seed must be a whole number >= 0"),
    ],
)
def test_a_bad_scenario_is_one_clear_error(kwargs, message: str) -> None:
    with pytest.raises(SimulationError, match=message):
        Scenario(**kwargs)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("0:250", r"speed 250 km/h is outside 0..200 km/h"),
        ("0:60,0:80", r"times must increase strictly"),
        ("-1:60", r"times start at 0 s or later"),
        ("0-60", r"'0-60' is not time_s:speed_kmh"),
    ],
)
def test_a_bad_speed_profile_is_one_clear_error(text: str, message: str) -> None:
    with pytest.raises(SimulationError, match=message):
        SpeedProfile.parse(text)


def test_write_csv_recording_writes_exactly_what_savetxt_wrote(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    t = 1e4 + np.arange(70001) / 500.0
    a = np.column_stack([rng.standard_normal(70001) * 3 + 9.81, -rng.random(70001), np.zeros(70001)])
    a[0, 2] = -0.0
    write_csv_recording(tmp_path / "fast.csv", t, a)
    buffer = io.StringIO()
    np.savetxt(buffer, np.column_stack([t, a]), fmt="%.6f", delimiter=",")
    assert (tmp_path / "fast.csv").read_text() == "time_s,a1,a2,a3\n" + buffer.getvalue()


def test_simulate_command_writes_a_recording_analyze_reads(tmp_path: Path, capsys) -> None:
    out = tmp_path / "run.csv"
    args = ["simulate", "-o", str(out), "--duration-s", "61", "--fault", "type_a:rear_outer:0.0@leading-left",
            "--speed-profile", "0:70,61:90", "--seed", "3", "--load", "full", "--track", "erri-high"]  # fmt: skip
    assert main(args) == 0
    summary = capsys.readouterr().out
    assert summary.startswith(f"{out}: 30500 samples at 500 Hz (61 s), full load, 0:70,61:90 km/h on erri-high, seed 3")
    scenario = read_sidecar(tmp_path / "run.json")
    assert scenario.faults == (parse_fault("type_a:rear_outer:0.0@leading-left"),)
    (tmp_path / "60s.toml").write_text('[processing]\nwindow_s = 60.0\n[decision]\nmethod = "thresholds"\n')
    assert main(["analyze", str(out), "--config", str(tmp_path / "60s.toml")]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 3  # header, columns, one 60 s window


def test_simulate_command_takes_sensors_and_rate_from_the_config(tmp_path: Path) -> None:
    config = tmp_path / "site.toml"
    config.write_text(
        '[sensors]\na1 = "trailing-right"\na2 = "trailing-left"\na3 = "leading-right"\n[processing]\nfs_hz = 200.0\n'
    )
    assert main(["simulate", "-o", str(tmp_path / "r.csv"), "--duration-s", "2", "--config", str(config), "-q"]) == 0
    scenario = read_sidecar(tmp_path / "r.json")
    assert scenario.fs_hz == 200.0
    assert scenario.geometry.corners == (Corner.TRAILING_RIGHT, Corner.TRAILING_LEFT, Corner.LEADING_RIGHT)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--track", "erri-medium"], "unknown track 'erri-medium': use one of perfect, erri-low"),
        (["--fault", "type_a:rear_outer@leading-left"], "expected three ':'-separated fields"),
        (["--fault", "type_a:rear_outer:0.0@front-left"], "unknown corner 'front-left'"),
        (["--duration-s", "-5"], "duration must be positive, got -5 s"),
        (["--speed-profile", "0:60,abc"], "'abc' is not time_s:speed_kmh"),
        (["--fault", "type_b::0.6@leading-left"], "type_b severity 0.6 is not a case of the paper's Table 3"),
    ],
)
def test_simulate_command_bad_arguments_are_one_line_and_status_2(tmp_path: Path, args, message: str) -> None:
    proc = subprocess.run([*BOGIEMON, "simulate", "-o", str(tmp_path / "x.csv"), *args], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.startswith("bogiemon: error: ") and message in proc.stderr
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert not (tmp_path / "x.csv").exists()


def test_simulate_command_into_a_missing_folder_is_a_user_error(tmp_path: Path, capsys) -> None:
    assert main(["simulate", "-o", str(tmp_path / "no" / "x.csv")]) == 2
    assert "the folder does not exist" in capsys.readouterr().err


def _run_on_a_terminal(args: list[str]) -> tuple[int, str]:
    """Run bogiemon with stderr on a real pseudo-terminal; (status, what the terminal showed)."""
    import os
    import pty

    master, slave = pty.openpty()
    proc = subprocess.Popen([*BOGIEMON, *args], stdout=subprocess.DEVNULL, stderr=slave)
    os.close(slave)
    shown = b""
    while True:
        try:
            data = os.read(master, 4096)
        except OSError:  # EIO: the child closed the terminal
            break
        if not data:
            break
        shown += data
    os.close(master)
    return proc.wait(), shown.decode(errors="replace")


def test_a_progress_bar_is_drawn_on_a_terminal_unless_quiet(tmp_path: Path) -> None:
    status, shown = _run_on_a_terminal(["simulate", "-o", str(tmp_path / "a.csv"), "--duration-s", "6"])
    assert status == 0
    assert "simulating 6 s [" in shown and "100%" in shown
    status, shown = _run_on_a_terminal(["simulate", "-o", str(tmp_path / "b.csv"), "--duration-s", "6", "--quiet"])
    assert status == 0 and shown == ""


def test_no_progress_bar_when_stderr_is_not_a_terminal(tmp_path: Path) -> None:
    proc = subprocess.run(
        [*BOGIEMON, "simulate", "-o", str(tmp_path / "a.csv"), "--duration-s", "2"], capture_output=True, text=True
    )
    assert proc.returncode == 0 and proc.stderr == ""
    assert proc.stdout.startswith(f"{tmp_path / 'a.csv'}: 1000 samples at 500 Hz (2 s)")


def test_a_fault_with_an_onset_leaves_the_run_healthy_until_then_and_faulty_after() -> None:
    fault = (parse_fault("type_a:rear_outer:0.0@leading-left"),)
    base: dict[str, Any] = dict(duration_s=8.0, seed=3, fs_hz=200.0)
    healthy = simulate(Scenario(**base))
    onset = simulate(Scenario(**base, faults=fault, fault_onset_s=4.0))
    faulty = simulate(Scenario(**base, faults=fault))
    n = int(4.0 * 200.0)
    # Identical to the healthy run up to the onset (same track, same state)...
    np.testing.assert_array_equal(onset.accel_mps2[:n], healthy.accel_mps2[:n])
    # ...then it departs from it, and ends up near the faulty run's behaviour, not the healthy one's.
    assert np.abs(onset.accel_mps2[n + 50 :] - healthy.accel_mps2[n + 50 :]).max() > 0.05
    late = slice(n + 400, None)  # two seconds after the onset: the transient has settled
    assert np.abs(onset.accel_mps2[late] - faulty.accel_mps2[late]).mean() < np.abs(onset.accel_mps2[late] - healthy.accel_mps2[late]).mean()


def test_the_onset_is_in_the_sidecar_and_checked() -> None:
    fault = (parse_fault("type_b::0.5@trailing-right"),)
    scenario = Scenario(duration_s=10.0, faults=fault, fault_onset_s=2.5)
    assert Scenario.from_dict(scenario.to_dict()) == scenario
    with pytest.raises(SimulationError, match="fault onset must lie in"):
        Scenario(duration_s=10.0, faults=fault, fault_onset_s=10.0)
    with pytest.raises(SimulationError, match="needs a fault"):
        Scenario(duration_s=10.0, fault_onset_s=1.0)


def test_without_numba_simulate_says_which_extra_to_install(tmp_path: Path) -> None:
    code = (
        "import sys; sys.modules['numba'] = None\n"  # as on a gateway installed without the sim extra
        "from bogiemon.cli.main import main\n"
        f"sys.exit(main(['simulate', '-o', {str(tmp_path / 'run.csv')!r}]))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 2
    assert "needs numba: install bogiemon with its 'sim' extra" in proc.stderr and "Traceback" not in proc.stderr
