"""Rigid-body kinematics of the bogie frame: three corner accelerations to bounce, pitch, roll.

Frame and sign conventions (used everywhere in bogiemon, and tested):
  x  along the bogie, positive towards the *leading* axle (the reference direction of travel);
  y  across the track, positive towards the *left* rail (looking in the direction of travel);
  z  vertical, positive *up*.
The bogie-frame centre is the origin; an axle box sits at x = +/- l (l = wheelbase / 2) and
y = +/- b (b = lateral sensor spacing / 2). For small motions the vertical acceleration at a
point (x, y) of the rigid frame is

    a(x, y) = a_bounce + x * a_pitch + y * a_roll

so a_bounce [m/s^2] is the centre's vertical acceleration, a_pitch [rad/s^2] is positive when
the leading end rises, and a_roll [rad/s^2] is positive when the left side rises.

With sensor 1 leading-left, sensor 2 leading-right and sensor 3 trailing-left (the paper's
layout) the inverse is exactly METHOD.md's  aB = (a2 + a3)/2, aP = (a1 - a3)/(2l),
aR = (a1 - a2)/(2b). Any other choice of three distinct corners is solved the same way, so the
signs follow the physical corners named in the config rather than the channel numbers.

If the wagon runs the other way round, x and y both change sign: a_pitch and a_roll flip, their
product does not. C_PR, and indicators 2, 3 and 4, are therefore independent of the direction
of travel; C_BR changes sign, indicator 1 (a standard deviation) does not.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


class Corner(enum.Enum):
    """An axle-box corner of the bogie frame, named for the reference direction of travel."""

    LEADING_LEFT = "leading-left"
    LEADING_RIGHT = "leading-right"
    TRAILING_LEFT = "trailing-left"
    TRAILING_RIGHT = "trailing-right"

    @property
    def x_sign(self) -> int:
        """+1 on the leading axle, -1 on the trailing axle."""
        return 1 if self.value.startswith("leading") else -1

    @property
    def y_sign(self) -> int:
        """+1 on the left rail, -1 on the right rail."""
        return 1 if self.value.endswith("left") else -1


PAPER_LAYOUT: tuple[Corner, Corner, Corner] = (
    Corner.LEADING_LEFT,
    Corner.LEADING_RIGHT,
    Corner.TRAILING_LEFT,
)


@dataclass(frozen=True)
class BogieGeometry:
    """Where the three accelerometers sit on the bogie frame.

    wheelbase_m is the paper's 2l, sensor_spacing_m its 2b; corners[i] is the corner of
    sensor i+1 (channel a{i+1}).
    """

    wheelbase_m: float = 1.80
    sensor_spacing_m: float = 2.0
    corners: tuple[Corner, Corner, Corner] = PAPER_LAYOUT

    def __post_init__(self) -> None:
        if not (self.wheelbase_m > 0 and self.sensor_spacing_m > 0):
            raise ValueError("wheelbase_m and sensor_spacing_m must be positive")
        if len(self.corners) != 3 or len(set(self.corners)) != 3:
            raise ValueError(f"three distinct sensor corners are needed, got {self.corners}")

    def positions_m(self) -> NDArray[np.float64]:
        """(3, 2) array of the sensors' (x, y) positions in metres."""
        half_l = self.wheelbase_m / 2.0
        half_b = self.sensor_spacing_m / 2.0
        return np.array([[c.x_sign * half_l, c.y_sign * half_b] for c in self.corners])

    def sensor_matrix(self) -> NDArray[np.float64]:
        """(3, 3) matrix F with [a1, a2, a3] = F @ [a_bounce, a_pitch, a_roll]: row i is (1, x_i, y_i)."""
        xy = self.positions_m()
        return np.column_stack([np.ones(3), xy[:, 0], xy[:, 1]])

    def modal_matrix(self) -> NDArray[np.float64]:
        """(3, 3) matrix T = F^-1 with [a_bounce, a_pitch, a_roll] = T @ [a1, a2, a3].

        Three distinct corners of a rectangle are never collinear, so F is always invertible.
        """
        return np.linalg.inv(self.sensor_matrix()).astype(np.float64, copy=False)


def to_modal(accel_mps2: NDArray[np.float64], geometry: BogieGeometry) -> NDArray[np.float64]:
    """Map (n, 3) sensor accelerations to (n, 3) columns a_bounce [m/s^2], a_pitch, a_roll [rad/s^2].

    The sample axis is 0.
    """
    accel = np.asarray(accel_mps2, dtype=np.float64)
    if accel.ndim != 2 or accel.shape[1] != 3:
        raise ValueError(f"expected an (n, 3) array of accelerations, got shape {accel.shape}")
    return accel @ geometry.modal_matrix().T


def from_modal(modal: NDArray[np.float64], geometry: BogieGeometry) -> NDArray[np.float64]:
    """Inverse of to_modal: (n, 3) [a_bounce, a_pitch, a_roll] to the three sensors' accelerations."""
    return np.asarray(modal, dtype=np.float64) @ geometry.sensor_matrix().T
