"""Accuracy indices J and Jrel of an estimated alignment per EN 13848 wavelength band.

Implements Munoz et al. 2021, Eq. 30: J = rms(xi_est - xi_real) and Jrel = J / rms(xi_real),
both after the same zero-phase band-pass (trolley.bands) of the estimate and the truth, in the
bands D1 (3-25 m), D2 (25-70 m), D3 (70-200 m) and the whole range 3-200 m (Tables 2-4).
Also the honesty of the reported sigmas: rms of (error / sigma) on the unfiltered alignment.

References
----------
Munoz, Ros, Urda, Escalona, IEEE Access 9 (2021), Eq. 30, Tables 2-4; EN 13848-1 (bands).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trolley.bands import BANDS, bandpass_wavelength

#: the bands of Munoz 2021 Tables 2-4: EN 13848 D1-D3 and the whole range
ACCURACY_BANDS: dict[str, tuple[float, float]] = {**BANDS, "3-200": (3.0, 200.0)}


@dataclass(frozen=True)
class BandAccuracy:
    """J (m), Jrel (-) and rms of the band-passed truth (m) in one band."""

    J_m: float
    Jrel: float
    rms_true_m: float


def uniform_grid(s_m, *values, step_m: float = 0.1):
    """Resample profiles given at increasing chainages onto a uniform grid (linear interpolation).

    Parameters
    ----------
    s_m : (N,) increasing chainages, m.
    values : (N,) profiles at s_m.
    step_m : grid step, m.

    Returns
    -------
    grid : (M,) chainages from s_m[0] in steps of step_m up to s_m[-1].
    resampled : one (M,) array per profile.
    """
    s = np.asarray(s_m, float)
    if len(s) < 2 or not np.all(np.diff(s) > 0):
        raise ValueError("chainages must be strictly increasing (the vehicle must move)")
    grid = s[0] + step_m * np.arange(int(np.floor((s[-1] - s[0]) / step_m + 1e-9)) + 1)
    return grid, [np.interp(grid, s, np.asarray(v, float)) for v in values]


def band_accuracy(s_m, estimate_m, truth_m, step_m: float = 0.1, trim_m: float = 0.0,
                  bands: dict[str, tuple[float, float]] | None = None) -> dict[str, BandAccuracy]:
    """J and Jrel per band (Munoz 2021 Eq. 30).

    Parameters
    ----------
    s_m : (N,) increasing chainages, m.
    estimate_m, truth_m : (N,) estimated and true alignment at s_m, m.
    step_m : uniform grid step for the band-pass, m.
    trim_m : chainage left out at each end after filtering (the filters' edge transients), m.
    bands : name -> (short, long) wavelengths, m; default :data:`ACCURACY_BANDS`.

    Returns
    -------
    dict band name -> BandAccuracy
    """
    grid, (est, tru) = uniform_grid(s_m, estimate_m, truth_m, step_m=step_m)
    inside = (grid >= grid[0] + trim_m) & (grid <= grid[-1] - trim_m)
    if inside.sum() < 2:
        raise ValueError(f"trim_m={trim_m} m leaves no samples of a {grid[-1] - grid[0]:.1f} m run")
    out = {}
    for name, (short, long) in (bands or ACCURACY_BANDS).items():
        e = bandpass_wavelength(est, step_m, short, long) - bandpass_wavelength(tru, step_m, short, long)
        t = bandpass_wavelength(tru, step_m, short, long)
        J = float(np.sqrt(np.mean(e[inside] ** 2)))
        r = float(np.sqrt(np.mean(t[inside] ** 2)))
        out[name] = BandAccuracy(J, J / r if r > 0 else float("inf"), r)
    return out


def honesty(estimate_m, sigma_m, truth_m) -> float:
    """rms of (estimate - truth) / sigma over the given samples (1 for honest sigmas)."""
    e = (np.asarray(estimate_m, float) - np.asarray(truth_m, float)) / np.asarray(sigma_m, float)
    return float(np.sqrt(np.mean(e ** 2)))
