"""Model B's track: a two-slope power-law spectrum per rail, a coherence model, dipped welds and joints.

Each rail's vertical profile has the one-sided PSD (n in cycles/m, S in m^2/(cycle/m))

    S(n) = G0 (n0 / n)^2 / ((1 + n / n_b) (1 + (n / n_r)^2)) * H(n),   H(n) = (n / n_lo)^4 / (1 + (n / n_lo)^4)

an n^-2 law at long waves (the slope of ISO 8608 road profiles and of measured track at 10-100 m)
turning to n^-3 below the break wavelength 1 / n_b (5 m), as short-wave track geometry falls off,
and to n^-5 below 1 / n_r (1.5 m), where the geometry gives way to rail roughness (tens of um
between 0.25 and 1 m, not the tenth of a mm an n^-3 law would reach); H fades out waves longer
than 1 / n_lo (120 m), and nothing shorter than `shortest_wavelength_m` is generated. Model B's
flexible wheelsets take the short waves that model A's rigid ones must leave out (A rolls its
spectra off below 1 m). G0 = S(n0) at n0 = 0.1 cycle/m is the roughness class
(config/y25_wagon_b.toml [irregularity.classes]).

The two rails have the same spectrum and the coherence gamma(n) = 1 / (1 + (n / n_c)^2): the
cross-spectrum is gamma S, so the rails move together at long waves (the track's level) and
independently at short ones. Model A generates the level and the cross-level as two independent
processes from the ERRI and FRA formulas instead.

Synthesis: a sum of harmonics on an FFT grid with deterministic amplitudes sqrt(2 S dn) and uniform
random phases (Shinozuka's method, where model A draws Gaussian amplitudes), one set of phases
common to both rails and one per rail, mixed as sqrt(gamma) common + sqrt(1 - gamma) own.

Discrete events, added to the random profile: dipped welds (continuously welded rail: positions
at exponential spacings about the class's mean, at least a quarter of it, each rail independently)
or dipped joints (jointed rail: every `event_spacing_m` on each rail, staggered by half a rail
length, with a little jitter); each a raised-cosine depression of the class's length and a depth
drawn exponentially about the class's mean depth (at most three times it).

The track names of model A are accepted and mapped to the B class of comparable roughness
([irregularity.names]), so one plan runs on both models.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.track import TRACKS, TrackProfile

FloatArray = NDArray[np.float64]
PERFECT = "perfect"


@dataclass(frozen=True)
class TrackClass:
    """One of model B's roughness classes."""

    name: str
    description: str
    psd_at_reference_m3: float  # G0 = S(n0), m^2/(cycle/m)
    events: str  # "welds", "joints" or "none"
    event_spacing_m: float
    dip_depth_m: float
    dip_length_m: float


@dataclass(frozen=True)
class TrackModel:
    """Model B's track description: the spectrum's shape and the class of one track name."""

    reference_wavenumber_cpm: float
    break_wavenumber_cpm: float
    roughness_wavenumber_cpm: float
    longest_wavelength_m: float
    shortest_wavelength_m: float
    coherence_wavenumber_cpm: float
    track_class: TrackClass | None  # None: the perfect track

    def rail_psd(self, n_cpm: FloatArray) -> FloatArray:
        """S(n) of one rail, m^2/(cycle/m), before the short-wave cut."""
        n = np.asarray(n_cpm, dtype=np.float64)
        if self.track_class is None:
            return np.zeros_like(n)
        out = np.zeros_like(n)
        pos = n > 0
        x = n[pos]
        n_lo = 1.0 / self.longest_wavelength_m
        highpass = (x / n_lo) ** 4 / (1.0 + (x / n_lo) ** 4)
        out[pos] = (
            self.track_class.psd_at_reference_m3 * (self.reference_wavenumber_cpm / x) ** 2
            / ((1.0 + x / self.break_wavenumber_cpm) * (1.0 + (x / self.roughness_wavenumber_cpm) ** 2)) * highpass
        )  # fmt: skip
        return out

    def coherence(self, n_cpm: FloatArray) -> FloatArray:
        """gamma(n) = |S_LR| / S of the two rails."""
        return 1.0 / (1.0 + (np.asarray(n_cpm, dtype=np.float64) / self.coherence_wavenumber_cpm) ** 2)


def track_model(parameter_set: dict[str, Any], name: str) -> TrackModel:
    """Model B's description of the track called `name` (one of model A's names)."""
    if name not in TRACKS:
        raise SimulationError(f"unknown track '{name}': use one of {', '.join(TRACKS)}")
    try:
        irr = parameter_set["vehicle"]["irregularity"]
        track_class = None
        if name != PERFECT:
            label = irr["names"][name]
            c = irr["classes"][label]
            track_class = TrackClass(
                name=label,
                description=str(c["description"]),
                psd_at_reference_m3=float(c["psd_at_reference_m3"]),
                events=str(c["events"]),
                event_spacing_m=float(c["event_spacing_m"]),
                dip_depth_m=float(c["dip_depth_m"]),
                dip_length_m=float(c["dip_length_m"]),
            )
            if track_class.events not in ("welds", "joints", "none"):
                raise SimulationError(f"model B track class {label}: events must be welds, joints or none, got '{track_class.events}'")
        return TrackModel(
            reference_wavenumber_cpm=float(irr["reference_wavenumber_cpm"]),
            break_wavenumber_cpm=float(irr["break_wavenumber_cpm"]),
            roughness_wavenumber_cpm=float(irr["roughness_wavenumber_cpm"]),
            longest_wavelength_m=float(irr["longest_wavelength_m"]),
            shortest_wavelength_m=float(irr["shortest_wavelength_m"]),
            coherence_wavenumber_cpm=float(irr["coherence_wavenumber_cpm"]),
            track_class=track_class,
        )
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, SimulationError):
            raise
        raise SimulationError(f"model B track parameters are incomplete or malformed: {exc!r}") from None


def _random_rails(model: TrackModel, n: int, ds_m: float, rng: np.random.Generator) -> tuple[FloatArray, FloatArray]:
    n_fft = 1 << max(4, int(np.ceil(np.log2(n))))
    freq = np.fft.rfftfreq(n_fft, d=ds_m).astype(np.float64, copy=False)
    dn = freq[1]
    s = model.rail_psd(freq)
    s[freq > 1.0 / model.shortest_wavelength_m] = 0.0
    gamma = model.coherence(freq)
    amplitude = np.sqrt(2.0 * s * dn) * (n_fft / 2.0)
    common, left, right = (np.exp(2j * np.pi * rng.random(freq.shape)) for _ in range(3))
    mix_c, mix_own = np.sqrt(gamma), np.sqrt(1.0 - gamma)
    z_left = np.fft.irfft(amplitude * (mix_c * common + mix_own * left), n=n_fft)[:n]
    z_right = np.fft.irfft(amplitude * (mix_c * common + mix_own * right), n=n_fft)[:n]
    return z_left, z_right


def event_positions_m(track_class: TrackClass, length_m: float, rng: np.random.Generator) -> tuple[FloatArray, FloatArray]:
    """Where the dips of the left and of the right rail lie along [0, length_m]."""
    spacing = track_class.event_spacing_m
    if track_class.events == "none" or spacing <= 0:
        return np.zeros(0), np.zeros(0)
    if track_class.events == "joints":
        first = rng.uniform(0.0, spacing)
        rails = []
        for stagger in (0.0, 0.5 * spacing):  # the right rail's joints half a rail length on
            x = np.arange(first + stagger, length_m, spacing)
            rails.append(x + rng.uniform(-0.02, 0.02, x.shape) * spacing)
        return rails[0], rails[1]
    count = int(length_m / spacing * 2) + 8
    welds = []
    for _ in range(2):  # each rail's welds on their own
        gaps = 0.25 * spacing + rng.exponential(0.75 * spacing, count)
        x = np.cumsum(gaps) - rng.uniform(0.0, gaps[0])
        welds.append(x[(x > 0) & (x < length_m)])
    return welds[0], welds[1]


def _add_dips(z: FloatArray, ds_m: float, positions_m: FloatArray, track_class: TrackClass, rng: np.random.Generator) -> None:
    depths = np.minimum(rng.exponential(track_class.dip_depth_m, positions_m.shape), 3.0 * track_class.dip_depth_m)
    half = 0.5 * track_class.dip_length_m
    for x0, depth in zip(positions_m, depths, strict=True):
        i0, i1 = max(int(np.ceil((x0 - half) / ds_m)), 0), min(int(np.floor((x0 + half) / ds_m)), z.size - 1)
        if i1 < i0:
            continue
        s = np.arange(i0, i1 + 1) * ds_m - x0
        z[i0 : i1 + 1] -= 0.5 * depth * (1.0 + np.cos(np.pi * s / half))


def generate_track(
    parameter_set: dict[str, Any],
    name: str,
    length_m: float,
    rng: np.random.Generator,
    ds_m: float = 0.05,
    fade_start_m: float = 0.0,
    fade_length_m: float = 0.0,
) -> TrackProfile:
    """Left and right rail profiles of model B over [0, length_m].

    Irregularities and dips are faded in with a smoothstep from fade_start_m over fade_length_m
    (nothing before), so a wagon at rest before fade_start_m starts without a jolt.
    """
    model = track_model(parameter_set, name)
    if not (length_m > 0 and ds_m > 0):
        raise ValueError(f"length_m ({length_m}) and ds_m ({ds_m}) must be positive")
    if model.shortest_wavelength_m < 4 * ds_m:
        raise SimulationError(
            f"model B track: shortest_wavelength_m ({model.shortest_wavelength_m}) needs at least 4 samples of {ds_m} m"
        )
    n = int(np.ceil(length_m / ds_m)) + 2
    if model.track_class is None:
        return TrackProfile(ds_m=ds_m, left_m=np.zeros(n), right_m=np.zeros(n))
    left, right = _random_rails(model, n, ds_m, rng)
    for z, positions in zip((left, right), event_positions_m(model.track_class, n * ds_m, rng), strict=True):
        _add_dips(z, ds_m, positions[positions > fade_start_m + fade_length_m], model.track_class, rng)  # none in the fade-in
    if fade_length_m > 0 or fade_start_m > 0:
        s = np.clip((np.arange(n) * ds_m - fade_start_m) / max(fade_length_m, ds_m), 0.0, 1.0)
        fade = s * s * (3.0 - 2.0 * s)
        left *= fade
        right *= fade
    return TrackProfile(ds_m=ds_m, left_m=left, right_m=right)
