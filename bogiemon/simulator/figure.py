"""The figure of docs/simulator.md: a healthy and a faulty run, bogie-frame accelerations and spectra.

Regenerate with `.venv/bin/python -m bogiemon.simulator.figure [-o docs/figures/simulator_healthy_vs_faulty.png]`
(needs the `report` extra: matplotlib).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy import signal

from bogiemon.detection import butter_sos, to_modal, xcorr_direct
from bogiemon.simulator.result import SimulationResult
from bogiemon.simulator.run import simulate_batch
from bogiemon.simulator.scenario import Scenario
from bogiemon.simulator.suspension import parse_fault

DEFAULT_OUTPUT = Path("docs/figures/simulator_healthy_vs_faulty.png")
FAULT = "type_a:rear_outer:0.0@leading-left"


def _conditioned_modal(result: SimulationResult) -> np.ndarray:
    """Bounce, pitch, roll after the detection core's 0.5 Hz high-pass (its first 2 s dropped)."""
    fs_hz = result.scenario.fs_hz
    sos = butter_sos(2, 0.5, fs_hz, "highpass")
    accel = result.accel_mps2
    zi = signal.sosfilt_zi(sos)[:, :, None] * accel[0][None, None, :]
    filtered = signal.sosfilt(sos, accel, axis=0, zi=zi)[0]
    return to_modal(filtered, result.scenario.geometry)[int(2 * fs_hz) :]


def render(output: Path, duration_s: float = 120.0, seed: int = 1) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    healthy, faulty = simulate_batch(
        [Scenario(duration_s=duration_s, seed=seed), Scenario(duration_s=duration_s, seed=seed, faults=(parse_fault(FAULT),))]
    )
    fs_hz = healthy.scenario.fs_hz
    fig, axes = plt.subplots(3, 2, figsize=(12, 10.5), constrained_layout=True)
    titles = ("healthy", f"faulty: {FAULT}")
    for col, (result, title) in enumerate(zip((healthy, faulty), titles, strict=True)):
        t = result.time_s
        show = (t >= 30.0) & (t < 32.0)
        ax = axes[0, col]
        for ch in range(3):
            corner = result.scenario.geometry.corners[ch].value
            ax.plot(t[show], result.accel_mps2[show, ch], lw=0.8, label=f"a{ch + 1} ({corner})")
        ax.set(title=f"{title}\nspecific force at the sensors (2 s)", xlabel="time (s)", ylabel="m/s$^2$")
        ax.legend(fontsize=8, loc="upper right")
        ax = axes[1, col]
        for ch in range(3):
            f, p = signal.welch(result.accel_mps2[:, ch] - result.accel_mps2[:, ch].mean(), fs=fs_hz, nperseg=4096)
            ax.semilogy(f, p, lw=0.8, label=f"a{ch + 1}")
        ax.set(xlim=(0, 60), ylim=(1e-5, 1e1), xlabel="frequency (Hz)", ylabel="PSD ((m/s$^2$)$^2$/Hz)")
        ax.set_title("spectra (Welch, 8 s segments)")
        ax.legend(fontsize=8)
        ax = axes[2, col]
        bounce, pitch, roll = _conditioned_modal(result).T
        window = slice(0, int(60 * fs_hz))
        lag_n = int(2 * fs_hz)
        lags = np.arange(-lag_n, lag_n + 1) / fs_hz
        for x, name in ((bounce, "bounce"), (pitch, "pitch")):
            c = xcorr_direct(x[window], roll[window], lag_n) / (np.std(x[window]) * np.std(roll[window]))
            ax.plot(lags, c, lw=0.9, label=f"C_{name[0].upper()}R / (sigma sigma), zero lag {c[lag_n]:+.2f}")
        ax.set(ylim=(-0.8, 0.8), xlabel="lag (s)", ylabel="correlation coefficient")
        ax.set_title("cross-correlation with roll (60 s window)")
        ax.axhline(0, color="k", lw=0.5)
        ax.legend(fontsize=8)
    fig.suptitle(
        f"Y25 wagon, full load, 80 km/h, ERRI low-level track, seed {seed}: leading bogie frame (bogiemon.simulator)", fontsize=11
    )
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, dpi=110)
    plt.close(fig)
    return output


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=DEFAULT_OUTPUT, help=f"PNG to write (default {DEFAULT_OUTPUT})")
    args = parser.parse_args()
    print(render(args.output))


if __name__ == "__main__":
    main()
