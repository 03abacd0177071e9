"""Synthetic bogie signals for daemon tests: independent modes (healthy-like) or coupled ones."""

from __future__ import annotations

import numpy as np

from bogiemon.detection import BogieGeometry, from_modal
from bogiemon.drivers.base import Block

FS_HZ = 100.0
GRAVITY_MPS2 = 9.81


def bogie_accel(duration_s: float, seed: int, pitch_roll_coupling: float = 0.0, scale: float = 1.0) -> np.ndarray:
    """(n, 3) sensor accelerations with gravity; pitch = noise + coupling * roll."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * FS_HZ)
    bounce, pitch, roll = rng.standard_normal((3, n))
    pitch = pitch + pitch_roll_coupling * roll
    modal = np.column_stack([bounce, 0.7 * pitch, 0.7 * roll]) * scale
    return from_modal(modal, BogieGeometry()) + GRAVITY_MPS2


def as_blocks(accel: np.ndarray, start_s: float = 1.7e9, block_n: int = 50, gap_at: set[int] | None = None) -> list[Block]:
    return [
        Block(start_s=start_s + i / FS_HZ, fs_hz=FS_HZ, accel_mps2=accel[i : i + block_n], gap_before=bool(gap_at and i in gap_at))
        for i in range(0, accel.shape[0], block_n)
    ]
