"""Rigid-body kinematics: each pure motion lands on its own channel, with the documented sign."""

import itertools

import numpy as np
import pytest

from bogiemon.detection import PAPER_LAYOUT, BogieGeometry, Corner, from_modal, to_modal
from bogiemon.detection.reference import modal_reference

ALL_LAYOUTS = list(itertools.permutations(Corner, 3))
GEOMETRIES = [BogieGeometry(1.8, 2.0, layout) for layout in ALL_LAYOUTS]


def corner_accels(geometry: BogieGeometry, bounce: float, pitch: float, roll: float) -> np.ndarray:
    """Accelerations at the sensors of a rigid frame, written from the convention itself."""
    half_l, half_b = geometry.wheelbase_m / 2, geometry.sensor_spacing_m / 2
    out = []
    for corner in geometry.corners:
        x = half_l if corner.value.startswith("leading") else -half_l
        y = half_b if corner.value.endswith("left") else -half_b
        out.append(bounce + x * pitch + y * roll)
    return np.array([out])


@pytest.mark.parametrize("geometry", GEOMETRIES, ids=lambda g: "/".join(c.value for c in g.corners))
def test_pure_bounce_maps_to_bounce_only(geometry: BogieGeometry) -> None:
    modal = to_modal(corner_accels(geometry, 1.7, 0.0, 0.0), geometry)
    np.testing.assert_allclose(modal, [[1.7, 0.0, 0.0]], atol=1e-12)


@pytest.mark.parametrize("geometry", GEOMETRIES, ids=lambda g: "/".join(c.value for c in g.corners))
def test_leading_end_rising_is_positive_pitch_only(geometry: BogieGeometry) -> None:
    modal = to_modal(corner_accels(geometry, 0.0, 0.4, 0.0), geometry)
    np.testing.assert_allclose(modal, [[0.0, 0.4, 0.0]], atol=1e-12)


@pytest.mark.parametrize("geometry", GEOMETRIES, ids=lambda g: "/".join(c.value for c in g.corners))
def test_left_side_rising_is_positive_roll_only(geometry: BogieGeometry) -> None:
    modal = to_modal(corner_accels(geometry, 0.0, 0.0, -0.3), geometry)
    np.testing.assert_allclose(modal, [[0.0, 0.0, -0.3]], atol=1e-12)


def test_paper_layout_is_methods_formulas() -> None:
    geometry = BogieGeometry(1.8, 2.0, PAPER_LAYOUT)
    a = np.random.default_rng(1).standard_normal((100, 3))
    a1, a2, a3 = a.T
    expected = np.column_stack([(a2 + a3) / 2, (a1 - a3) / 1.8, (a1 - a2) / 2.0])
    np.testing.assert_allclose(to_modal(a, geometry), expected, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("geometry", GEOMETRIES, ids=lambda g: "/".join(c.value for c in g.corners))
def test_matrix_inverse_equals_relabelled_paper_formulas(geometry: BogieGeometry) -> None:
    a = np.random.default_rng(2).standard_normal((50, 3))
    np.testing.assert_allclose(to_modal(a, geometry), modal_reference(a, geometry), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(from_modal(to_modal(a, geometry), geometry), a, rtol=1e-12, atol=1e-12)


def test_reversed_direction_flips_pitch_and_roll_but_not_their_product() -> None:
    forward = BogieGeometry(corners=PAPER_LAYOUT)
    # The same physical sensors seen from the other direction: leading<->trailing, left<->right.
    swap = {
        Corner.LEADING_LEFT: Corner.TRAILING_RIGHT,
        Corner.LEADING_RIGHT: Corner.TRAILING_LEFT,
        Corner.TRAILING_LEFT: Corner.LEADING_RIGHT,
        Corner.TRAILING_RIGHT: Corner.LEADING_LEFT,
    }
    backward = BogieGeometry(corners=tuple(swap[c] for c in PAPER_LAYOUT))  # type: ignore[arg-type]
    a = np.random.default_rng(3).standard_normal((200, 3))
    fwd, bwd = to_modal(a, forward), to_modal(a, backward)
    np.testing.assert_allclose(bwd[:, 0], fwd[:, 0], atol=1e-12)
    np.testing.assert_allclose(bwd[:, 1:], -fwd[:, 1:], atol=1e-12)
    np.testing.assert_allclose(bwd[:, 1] * bwd[:, 2], fwd[:, 1] * fwd[:, 2], atol=1e-12)


def test_geometry_scales_pitch_and_roll_by_the_lever_arms() -> None:
    geometry = BogieGeometry(wheelbase_m=2.0, sensor_spacing_m=1.0)
    modal = to_modal(np.array([[1.0, 0.0, 0.0]]), geometry)  # only the leading-left sensor moves
    np.testing.assert_allclose(modal, [[0.0, 0.5, 1.0]], atol=1e-12)


def test_two_sensors_on_one_corner_are_rejected() -> None:
    with pytest.raises(ValueError, match="distinct"):
        BogieGeometry(corners=(Corner.LEADING_LEFT, Corner.LEADING_LEFT, Corner.TRAILING_LEFT))


def test_to_modal_rejects_a_wrong_shape() -> None:
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        to_modal(np.zeros((10, 2)), BogieGeometry())
