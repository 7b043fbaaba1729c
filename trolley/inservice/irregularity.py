"""Track irregularities for the in-service truth simulator: random realisations from a published
PSD and the harmonic alignment of the resonance case.

Implements the irregularity inputs of Munoz 2021 Sec. V-A (vertical and lateral irregularities
of both rails generated from analytical PSDs by the method of Claus & Schiehlen [28]) and the
harmonic alignment of Sec. V-E (Case 2: 1 mm at the wavelength of the first lateral mode).

Spectrum
--------
The German track spectra for *low* disturbance, in the form Claus & Schiehlen fit for vehicle
dynamics (the paper's reference [28]); one-sided in the spatial angular frequency Omega (rad/m),
variance = integral over (0, inf) of S dOmega (the same functions
:func:`trolley.tgms.simulate.irregularity_psd` uses; they are reused here, not repeated)::

    S_al(O) = A_a Oc^2 / ((O^2 + Or^2)(O^2 + Oc^2))                 alignment        m^2/(rad/m)
    S_vp(O) = A_v Oc^2 / ((O^2 + Or^2)(O^2 + Oc^2))                 vertical profile
    S_cl(O) = A_v b^-2 Oc^2 O^2 / ((O^2+Or^2)(O^2+Oc^2)(O^2+Os^2))  cross-level angle  rad^2/(rad/m)

Oc = 0.8246, Or = 0.0206, Os = 0.4380 rad/m, A_a = 2.119e-7 m rad, A_v = 4.032e-7 m rad,
b = 0.75 m. The gauge is constant (the paper's assumption, Sec. II), so both rails carry the
same lateral irregularity: alignment = u_y^lr = u_y^rr (Eq. 1).

Realisation
-----------
Sum of cosines with deterministic amplitudes and uniform random phases on the FFT grid of the
track (Claus & Schiehlen's method): for Omega_k = 2 pi k / L in the band (default wavelengths
1-300 m), x(s) = sum_k sqrt(2 S(Omega_k) dOmega) cos(Omega_k s + phi_k), evaluated with one
inverse real FFT. Its mean square over the grid equals sum_k S(Omega_k) dOmega exactly, the
Riemann sum of the PSD integral over the band (tested against scipy.integrate.quad).

Lead-in
-------
The simulator starts the vehicle ``lead_in_m`` before chainage 0, with all irregularities
multiplied by a raised-cosine ramp from 0 at the start of the grid to 1 at half the lead-in, so
that the vehicle starts at rest on a perfect track and has settled by chainage 0.

Signs (internal, the paper's track frame): lateral positive to the LEFT, vertical positive UP,
cross level positive when the LEFT rail is higher. Files convert at the edge (survey.inservice_io).

References
----------
S. Munoz et al., IEEE Access 9 (2021) 60010-60025, Sec. V-A, V-E, Eq. 1.
H. Claus, W. Schiehlen, "Modeling and simulation of railway bogie structural vibrations",
Vehicle System Dynamics 29 (1998) 538-552 (German track spectra, low disturbance).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from trolley.tgms.simulate import irregularity_psd

#: grid step of the irregularity realisations, m
GRID_STEP_M = 0.1
#: default band of the random realisations (shortest, longest wavelength), m
PSD_BAND_M = (1.0, 300.0)
#: German spectrum's reference half distance b (m) that turns the cross-level angle into heights
SPECTRUM_HALF_GAUGE_M = 0.75


@dataclass(frozen=True)
class TrackIrregularity:
    """Irregularities of a straight or constant-curvature track as functions of chainage s.

    Attributes
    ----------
    s_m : (N,) uniform chainage grid, increasing; starts ``lead_in_m`` before 0.
    lateral_m : (N,) alignment xi_a = (u_y^lr + u_y^rr) / 2 (Eq. 1), positive to the left.
    vertical_m : (N,) vertical profile xi_vp = (u_z^lr + u_z^rr) / 2, positive up.
    cross_level_m : (N,) cross level xi_cl = u_z^lr - u_z^rr (left rail higher positive).
    lead_in_m : length before chainage 0 (ramped in, see the module docstring).
    """

    s_m: np.ndarray
    lateral_m: np.ndarray
    vertical_m: np.ndarray
    cross_level_m: np.ndarray
    lead_in_m: float

    def __post_init__(self):
        n = len(self.s_m)
        for name in ("lateral_m", "vertical_m", "cross_level_m"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"TrackIrregularity.{name}: length {len(getattr(self, name))} != len(s_m) {n}")
        if n < 4 or not np.all(np.diff(self.s_m) > 0):
            raise ValueError("TrackIrregularity.s_m must be increasing with at least 4 points")

    @property
    def end_m(self) -> float:
        """Last chainage of the grid, m."""
        return float(self.s_m[-1])

    def spline(self) -> CubicSpline:
        """Cubic spline of (lateral, vertical, cross level) in s; derivatives via ``spline(s, nu)``."""
        return CubicSpline(self.s_m, np.column_stack([self.lateral_m, self.vertical_m, self.cross_level_m]))

    def at(self, s_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lateral, vertical, cross level) at arbitrary chainages inside the grid, m."""
        v = self.spline()(np.asarray(s_m, float))
        return v[..., 0], v[..., 1], v[..., 2]

    def plus(self, other: "TrackIrregularity") -> "TrackIrregularity":
        """The sum of two irregularities on the same grid (Munoz 2021 Sec. V-E Case 3)."""
        if len(other.s_m) != len(self.s_m) or not np.allclose(other.s_m, self.s_m):
            raise ValueError("TrackIrregularity.plus: the two grids differ (use the same length_m and lead_in_m)")
        return TrackIrregularity(self.s_m, self.lateral_m + other.lateral_m, self.vertical_m + other.vertical_m,
                                 self.cross_level_m + other.cross_level_m, self.lead_in_m)

    def scaled(self, lateral: float = 1.0, vertical: float = 1.0) -> "TrackIrregularity":
        """A copy with the lateral and the vertical irregularities (profile and cross level) scaled."""
        return TrackIrregularity(self.s_m, lateral * self.lateral_m, vertical * self.vertical_m,
                                 vertical * self.cross_level_m, self.lead_in_m)


def track_grid(length_m: float, lead_in_m: float, step_m: float = GRID_STEP_M) -> tuple[np.ndarray, np.ndarray]:
    """Chainage grid from -lead_in_m to length_m + 2 m and the lead-in ramp on it.

    Returns
    -------
    s_m : (N,) grid.
    ramp : (N,) raised cosine, 0 at the grid start, 1 from -lead_in_m / 2 on.
    """
    if not (length_m > 0 and lead_in_m >= 0 and step_m > 0):
        raise ValueError(f"track_grid: need length_m > 0, lead_in_m >= 0, step_m > 0; got {length_m}, {lead_in_m}, {step_m}")
    n = int(np.ceil((length_m + 2.0 + lead_in_m) / step_m)) + 1
    s = -lead_in_m + step_m * np.arange(n)
    if lead_in_m == 0:
        return s, np.ones(n)
    x = np.clip((s + lead_in_m) / (0.5 * lead_in_m), 0.0, 1.0)
    return s, 0.5 - 0.5 * np.cos(np.pi * x)


def psd_realisation(kind: str, s_m: np.ndarray, rng: np.random.Generator,
                    band_m: tuple[float, float] = PSD_BAND_M) -> np.ndarray:
    """One realisation of the German low-disturbance spectrum ``kind`` on a uniform grid.

    Parameters
    ----------
    kind : "alignment", "vertical" (m) or "cross_level_angle" (rad), as in
        :func:`trolley.tgms.simulate.irregularity_psd`.
    s_m : (N,) uniform grid.
    rng : random generator (draws N // 2 + 1 phases).
    band_m : (shortest, longest) wavelength kept, m.

    Returns
    -------
    (N,) realisation; its mean square is sum_k S(Omega_k) dOmega over the band (module docstring).
    """
    n = len(s_m)
    ds = float(s_m[1] - s_m[0])
    omega = 2.0 * np.pi * np.fft.rfftfreq(n, ds)
    d_omega = omega[1] - omega[0]
    keep = (omega >= 2.0 * np.pi / band_m[1]) & (omega <= 2.0 * np.pi / band_m[0]) & (omega > 0)
    if n % 2 == 0:
        keep[-1] = False  # the Nyquist bin has no phase freedom
    amp = np.where(keep, np.sqrt(2.0 * irregularity_psd(kind, np.where(keep, omega, 1.0)) * d_omega), 0.0)
    spec = amp * np.exp(1j * rng.uniform(0.0, 2.0 * np.pi, len(omega)))
    return np.fft.irfft(spec, n) * (n / 2.0)


def psd_band_variance(kind: str, step_m: float,
                      band_m: tuple[float, float] = PSD_BAND_M) -> float:
    """Integral of the PSD over the band, int S dOmega (the variance a realisation should have)."""
    from scipy.integrate import quad
    lo, hi = 2.0 * np.pi / band_m[1], min(2.0 * np.pi / band_m[0], np.pi / step_m)
    return float(quad(lambda o: float(irregularity_psd(kind, np.array(o))), lo, hi, limit=200)[0])


def irregularity_from_psd(length_m: float, seed: int = 0, lead_in_m: float = 100.0,
                          lateral_scale: float = 1.0, vertical_scale: float = 1.0,
                          step_m: float = GRID_STEP_M, band_m: tuple[float, float] = PSD_BAND_M) -> TrackIrregularity:
    """Random alignment, vertical profile and cross level from the German low-disturbance spectra.

    Parameters
    ----------
    length_m : surveyed length after chainage 0, m.
    seed : random seed.
    lead_in_m : ramped-in length before chainage 0 (must cover the vehicle length plus settling).
    lateral_scale, vertical_scale : multipliers of the spectra's amplitudes (0 switches off).
    step_m : grid step, m.
    band_m : (shortest, longest) wavelength, m.

    Returns
    -------
    TrackIrregularity (Munoz 2021 Sec. V-A).
    """
    s, ramp = track_grid(length_m, lead_in_m, step_m)
    rng = np.random.default_rng(seed)
    lat = psd_realisation("alignment", s, rng, band_m)
    vp = psd_realisation("vertical", s, rng, band_m)
    cl = 2.0 * SPECTRUM_HALF_GAUGE_M * psd_realisation("cross_level_angle", s, rng, band_m)
    return TrackIrregularity(s, lateral_scale * ramp * lat, vertical_scale * ramp * vp,
                             vertical_scale * ramp * cl, float(lead_in_m))


def harmonic_irregularity(length_m: float, wavelength_m: float, amplitude_m: float, lead_in_m: float = 100.0,
                          step_m: float = GRID_STEP_M) -> TrackIrregularity:
    """Harmonic alignment xi = A sin(2 pi s / wavelength), no vertical irregularity (Munoz 2021 Sec. V-E, Case 2).

    Parameters
    ----------
    length_m : surveyed length, m.
    wavelength_m : wavelength, m (> 0); the resonance case uses V / f_1 (see vehicle.first_lateral_mode).
    amplitude_m : amplitude A, m (1e-3 in the paper).
    lead_in_m : ramped-in length before chainage 0.
    step_m : grid step, m.
    """
    if not wavelength_m > 0:
        raise ValueError(f"harmonic_irregularity: wavelength_m must be > 0, got {wavelength_m}")
    s, ramp = track_grid(length_m, lead_in_m, step_m)
    z = np.zeros_like(s)
    return TrackIrregularity(s, amplitude_m * ramp * np.sin(2.0 * np.pi * s / wavelength_m), z, z.copy(),
                             float(lead_in_m))
