"""The settings of the sensor checks, in a module of their own: the checks (health, gating, the
noise floor, the structure) each read them, and none of them is above the others."""

from __future__ import annotations

from dataclasses import dataclass

# The checks of the sensors' layout that commissioning can put in force (judgement/structure.py).
LAYOUT_CHECKS: tuple[str, ...] = ("low", "diagonal", "other", "quadrature")


@dataclass(frozen=True)
class HealthSettings:
    standstill_rms_mps2: float = 0.05  # every channel below this: the wagon stands
    min_excitation_rms_mps2: float = 0.3  # median channel RMS needed to judge the suspension
    # The quietest hop's RMS over the loudest's (median channel) below this: a stop or start inside.
    min_hop_rms_ratio: float = 0.25
    flat_rms_mps2: float = 0.02  # a channel below this while another moves is flat
    stuck_repeat_fraction: float = 0.2  # share of samples equal to the previous one
    # One value held this long while the wagon moves: a converter that froze within the window.
    # Healthy, noiseless 16 g / 16-bit sensors hold one value under 0.2 s even at 10 km/h in tare.
    stuck_run_s: float = 1.0
    clip_level_mps2: float = 155.0  # |a| at or above this is clipping (16 g full scale = 156.9)
    clipped_fraction: float = 1e-4  # share of clipped samples that makes a channel unusable
    noise_ratio: float = 2.0  # a channel's RMS over the median of the three
    noise_low_band_ratio: float = 3.2  # a channel's power at 0.5-1 Hz over the median of the three
    # A same-rail sensor's 0.5-1 Hz multiple coherence with the other two below this: noisy (SNR < 3).
    noise_coherence: float = 0.75
    max_rms_mps2: float = 50.0  # no bogie frame in service gives this much RMS
    max_gaps_per_hour: int = 6  # more gaps than this in the last hour: dropouts
    gravity_mps2: float = 9.81  # a channel's mean below -half of it, another's above +half: inverted
    # The checks that assume a real frame's spectra (coherence and low-band noise, the layout).
    structure_checks: bool = True
    # The layout checks in force (LAYOUT_CHECKS), learned at commissioning; none on an uncommissioned wagon.
    layout_checks: tuple[str, ...] = ()
    layout_low_coherence: float = -0.2  # "low": each channel's 0.5-2 Hz coherency with another above this
    layout_diagonal_coherence: float = -0.3  # "diagonal": the diagonal pair's 16-64 Hz coherency below this
    layout_other_margin: float = 0.0  # "other": the other pairs' 16-64 Hz coherency above the diagonal's by this
    layout_quadrature_margin: float = 0.0  # "quadrature": bounce-pitch above bounce-roll quadrature by this
    # The noise floor, learned at commissioning (learn_noise_floor): per channel the smallest floor
    # its healthy windows showed, (m/s^2)^2/Hz, and the largest ratio of it to the other two
    # channels' (their geometric mean); empty on a wagon not commissioned: not in force.
    noise_floor_psd: tuple[float, ...] = ()
    noise_floor_ratio: tuple[float, ...] = ()
    # A floor this many times both of those is a noisy sensor (a prior: judgement/noise_floor.py).
    noise_floor_margin: float = 1.8
    # A sensor flagged noisy by the noise floor alone (noise no other check saw, too faint to move the
    # couplings of 2-64 Hz) holds back no judgement of the suspension: the window is judged on its
    # couplings, and the sensor reported beside it (judgement/health.py, "A SENSOR FAULT NEVER HIDES A
    # SUSPENSION FAULT"). False judges nothing under any sensor problem: what the lab compares with.
    judge_through_floor_noise: bool = True

    def __post_init__(self) -> None:
        unknown = sorted(set(self.layout_checks) - set(LAYOUT_CHECKS))
        if unknown:
            raise ValueError(f"unknown layout checks {unknown}: use some of {list(LAYOUT_CHECKS)}")
        if len(self.noise_floor_psd) != len(self.noise_floor_ratio) or len(self.noise_floor_psd) not in (0, 3):
            raise ValueError("noise_floor_psd and noise_floor_ratio need one value per channel (three each), or none")
