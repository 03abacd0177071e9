"""Synthetic bogie signals for daemon tests: independent modes (healthy-like) or coupled ones."""

from __future__ import annotations

import numpy as np

from bogiemon.detection import BogieGeometry, from_modal
from bogiemon.drivers.base import Block

FS_HZ = 100.0
GRAVITY_MPS2 = 9.81


def short_windows_config(clear_after_windows: int | None = None, state_dir: object | None = None) -> str:
    """The daemon tests' config text: short windows over these synthetic signals, the threshold
    method on I4n with a fixed load, and the structure checks off. One copy for every test that
    runs the monitor, the service or replay on them (the `short_config` fixture writes it)."""
    clear = f"clear_after_windows = {clear_after_windows}\n" if clear_after_windows is not None else ""
    state = f'[state]\ndirectory = "{state_dir}"\n' if state_dir is not None else ""
    return f"""
[processing]
fs_hz = {FS_HZ}
window_s = 6.0
hop_s = 2.0
max_lag_s = 1.0
[health]
# White-noise modes have none of a bogie frame's structure: no structure checks on them.
structure_checks = false
[decision]
# These tests exercise the machinery with short windows: the per-indicator method, fixed load.
method = "thresholds"
load = "full"
confirm_k = 2
confirm_n = 3
{clear}[decision.thresholds.full.i4_norm]
warning = 0.2
alarm = 0.3
{state}"""


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
