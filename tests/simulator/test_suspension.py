"""The primary suspension: the coil nest against the paper's tables, the friction element, fault syntax."""

import hashlib
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bogiemon.detection import Corner
from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.params import default_parameter_set
from bogiemon.simulator.suspension import Fault, friction_step, parse_fault
from bogiemon.simulator.vehicle import build_model, static_equilibrium

SHIPPED_TABLES = Path(__file__).resolve().parents[2] / "config" / "y25_fault_cases.toml"
# SHA-256 of the paper's tables as transcribed in ../shared/paper/y25_fault_cases.toml (the copy
# in config/ must stay verbatim; the shared folder is not part of a clone, so its digest is here).
PAPER_TABLES_SHA256 = "2511de13c328e6b5d5f146af63120e3da118f3729ec5427b28b2120979b5eda4"
PARAMS = default_parameter_set()
CASES = PARAMS["fault_cases"]


def test_the_shipped_fault_tables_are_the_papers() -> None:
    assert hashlib.sha256(SHIPPED_TABLES.read_bytes()).hexdigest() == PAPER_TABLES_SHA256
    assert tomllib.loads(SHIPPED_TABLES.read_text()) == CASES


def _faulty_corner_state(load: str, fault: Fault) -> tuple[float, float]:
    """(tangent Kz at the static load, Fs) of the leading-left corner under `fault`."""
    model = build_model(PARAMS, load, (fault,))
    rest = static_equilibrium(model)
    compression = -(model.corner_rows() @ rest.q)
    corner = model.corners[0]
    return corner.tangent_stiffness_n_per_m(float(compression[0])), corner.fs_n


@pytest.mark.parametrize("load", ["full", "tare"])
def test_every_type_a_case_gets_the_tables_kz_and_fs(load: str) -> None:
    checked = 0
    for position, table in CASES["type_a"][load].items():
        for severity, (kz, fs) in table.items():
            fault = Fault(kind="type_a", corner=Corner.LEADING_LEFT, position=position, severity=float(severity))
            assert _faulty_corner_state(load, fault) == (pytest.approx(kz, rel=1e-12), fs)
            checked += 1
    assert checked == (16 if load == "full" else 8)


@pytest.mark.parametrize("load", ["full", "tare"])
def test_the_healthy_corner_has_the_tables_kz_and_fs(load: str) -> None:
    fault = Fault(kind="type_b", corner=Corner.LEADING_LEFT, severity=1.0)
    assert _faulty_corner_state(load, fault) == (pytest.approx(CASES["healthy"][load]["Kz"]), CASES["healthy"][load]["Fs"])


def test_type_b_uses_table_3s_published_values_and_keeps_kz() -> None:
    for severity, fs in [(0.5, 11.6e3), (0.75, 16.74e3), (1.25, 27.91e3), (1.5, 33.49e3)]:
        fault = Fault(kind="type_b", corner=Corner.LEADING_LEFT, severity=severity)
        assert _faulty_corner_state("full", fault) == (pytest.approx(2.56e6), fs)


def test_inner_coils_do_not_touch_in_tare() -> None:
    """Tare, front inner broken: the corner is exactly the healthy one at rest (Kz 1.0e6, Fs 2.12 kN)."""
    fault = Fault(kind="type_a", corner=Corner.LEADING_LEFT, position="front_inner", severity=0.0)
    assert _faulty_corner_state("tare", fault) == (pytest.approx(1.0e6), 2.12e3)


def test_custom_sets_the_corners_tangent_kz_and_fs() -> None:
    fault = parse_fault("custom:1.9e6:12e3@leading-left")
    assert _faulty_corner_state("full", fault) == (pytest.approx(1.9e6), 12e3)
    assert _faulty_corner_state("tare", fault) == (pytest.approx(1.9e6), 12e3)


def test_friction_loop_under_a_slow_stroke_has_width_two_fs() -> None:
    fs_n, stick = 16.51e3, 2.0e7
    stroke = 0.01 * np.sin(np.linspace(0, 4 * np.pi, 20001))  # two slow cycles of +/-10 mm
    slider, force = 0.0, np.empty_like(stroke)
    for i, u in enumerate(stroke):
        force[i], slider = friction_step(float(u), slider, stick, fs_n)
    # The second cycle (a closed loop): the force where the stroke crosses zero going up and down.
    crossings = np.flatnonzero(np.diff(np.sign(stroke[10000:])) != 0) + 10000
    going_up = [force[i] for i in crossings if stroke[i + 1] > stroke[i]]
    going_down = [force[i] for i in crossings if stroke[i + 1] < stroke[i]]
    assert going_up and going_down
    assert min(going_up) - max(going_down) == pytest.approx(2 * fs_n, rel=1e-9)
    assert np.max(np.abs(force)) == pytest.approx(fs_n, rel=1e-12)


def test_friction_sticks_below_fs_without_drift() -> None:
    slider = 0.0
    for _ in range(1000):
        force, slider = friction_step(1e-4, slider, 2e7, 16.51e3)  # 2 kN < Fs
    assert (force, slider) == (pytest.approx(2e3), 0.0)


@pytest.mark.parametrize(
    ("spec", "expected"),
    [
        ("type_a:rear_outer:0.0@leading-left", Fault("type_a", Corner.LEADING_LEFT, "leading", "rear_outer", 0.0)),
        ("type_b::0.5@trailing-right", Fault("type_b", Corner.TRAILING_RIGHT, "leading", None, 0.5)),
        (
            "type_a:front_inner:2.0@trailing-bogie:leading-right",
            Fault("type_a", Corner.LEADING_RIGHT, "trailing", "front_inner", 2.0),
        ),
        ("custom:2.06e6:10690@trailing-left", Fault("custom", Corner.TRAILING_LEFT, kz_n_per_m=2.06e6, fs_n=10690.0)),
    ],
)
def test_fault_specs_parse_and_print_back(spec: str, expected: Fault) -> None:
    fault = parse_fault(spec)
    assert fault == expected
    assert parse_fault(fault.spec()) == fault
    assert Fault.from_dict(fault.to_dict()) == fault


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("type_a:rear_outer:0.0", r"expected KIND:POSITION:SEVERITY@CORNER"),
        ("type_a:rear_outer:0.0@front-left", r"unknown corner 'front-left': use one of leading-left"),
        ("type_a:middle:0.0@leading-left", r"type_a needs a spring position, one of front_outer"),
        ("type_a:rear_outer:half@leading-left", r"the severity is not a number: 'half'"),
        ("type_c::0.5@leading-left", r"unknown fault kind 'type_c'"),
        ("type_b::0.5:1@leading-left", r"expected three ':'-separated fields"),
        ("custom:-1:100@leading-left", r"custom needs Kz > 0 N/m and Fs >= 0 N"),
        ("type_b::0.5@middle-bogie:leading-left", r"unknown bogie 'middle-bogie'"),
    ],
)
def test_a_malformed_fault_is_one_clear_error(spec: str, message: str) -> None:
    with pytest.raises(SimulationError, match=message):
        parse_fault(spec)


def test_a_severity_outside_the_tables_names_the_cases() -> None:
    with pytest.raises(SimulationError, match=r"type_b severity 0.6 is not a case of the paper's Table 3 \(full\)"):
        build_model(PARAMS, "full", (parse_fault("type_b::0.6@leading-left"),))


def test_two_faults_at_one_corner_are_refused() -> None:
    faults = (parse_fault("type_b::0.5@leading-left"), parse_fault("type_a:rear_outer:0.0@leading-left"))
    with pytest.raises(SimulationError, match="two faults at leading-left"):
        build_model(PARAMS, "full", faults)


@given(
    kind=st.sampled_from(["type_a", "type_b", "custom"]),
    corner=st.sampled_from(list(Corner)),
    bogie=st.sampled_from(["leading", "trailing"]),
    position=st.sampled_from(["front_outer", "front_inner", "rear_outer", "rear_inner"]),
    severity=st.sampled_from([0.0, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0]),
    kz=st.floats(1e4, 1e8),
    fs=st.floats(0.0, 1e5),
)
def test_any_fault_prints_as_a_spec_that_parses_back_to_it(kind, corner, bogie, position, severity, kz, fs) -> None:
    if kind == "custom":
        fault = Fault(kind, corner, bogie, kz_n_per_m=kz, fs_n=fs)
    else:
        fault = Fault(kind, corner, bogie, position if kind == "type_a" else None, severity)
    assert parse_fault(fault.spec()) == fault


@given(
    strokes=st.lists(st.floats(-0.02, 0.02), min_size=1, max_size=60),
    fs_n=st.floats(0.0, 4e4),
    stick=st.floats(1e6, 1e8),
)
def test_the_friction_force_never_exceeds_fs_and_sticking_never_moves_the_slider(strokes, fs_n, stick) -> None:
    slider = 0.0
    for u in strokes:
        force, new_slider = friction_step(u, slider, stick, fs_n)
        assert abs(force) <= fs_n * (1 + 1e-12)
        if abs(stick * (u - slider)) <= fs_n:
            assert new_slider == slider and force == stick * (u - slider)
        else:
            assert abs(force) == fs_n and force == pytest.approx(stick * (u - new_slider), abs=1e-6 * max(fs_n, 1.0))
        slider = new_slider
