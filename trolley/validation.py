"""Errors of a processed trajectory against the simulator's truth, in track directions.

Used by the tests, the accuracy benchmark and ``trolley demo``: the error of the smoothed track
reference point against the truth at the same instants, split into lateral (positive right of
the true heading), longitudinal and vertical, each beside its own 1-sigma.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trolley.trackgeometry import lateral_sigma


@dataclass
class TrackErrors:
    """Errors (m) and 1-sigmas (m) at the moving samples of a trajectory."""

    lateral_m: np.ndarray
    longitudinal_m: np.ndarray
    vertical_m: np.ndarray
    sigma_lateral_m: np.ndarray
    sigma_longitudinal_m: np.ndarray
    sigma_vertical_m: np.ndarray

    def rms_m(self) -> tuple[float, float, float]:
        """RMS of the lateral, longitudinal and vertical errors."""
        return tuple(float(np.sqrt(np.mean(e**2))) for e in (self.lateral_m, self.longitudinal_m, self.vertical_m))

    def normalised_rms(self) -> tuple[float, float, float]:
        """RMS of error / sigma (1 when the sigmas are honest)."""
        pairs = ((self.lateral_m, self.sigma_lateral_m), (self.longitudinal_m, self.sigma_longitudinal_m),
                 (self.vertical_m, self.sigma_vertical_m))
        return tuple(float(np.sqrt(np.mean((e / s) ** 2))) for e, s in pairs)


def track_errors(t_s, distance_m, enh_m, sigma_enh_m, truth, cov_EN_m2=None) -> TrackErrors:
    """Errors of a trajectory (times, odometer distance, E/N/H and their sigmas) against the truth.

    Parameters
    ----------
    t_s, distance_m : (K,) times and odometer distance of the trajectory samples.
    enh_m, sigma_enh_m : (K, 3) estimated E, N, H and their 1-sigmas.
    cov_EN_m2 : (K,) covariance of E and N (``Trajectory.cov_EN_m2``); None takes it as 0, which
        makes the lateral and longitudinal sigmas wrong by the E-N correlation (RLG: lateral
        error/sigma 0.90 without it, 1.04 with it, over 64 seeds).
    truth : an object with arrays ``t_s, E_m, N_m, H_m, yaw_rad`` (``trolley.truthsim.TruthTrack``;
        with a projected grid, ``truth.geometry.grid``, the true yaw is turned to the grid bearing).

    Returns
    -------
    TrackErrors at the samples where the trolley moves (standing samples repeat one point).
    """
    moving = np.r_[True, np.diff(distance_m) > 1e-4]
    t = t_s[moving]
    te = np.interp(t, truth.t_s, truth.E_m)
    tn = np.interp(t, truth.t_s, truth.N_m)
    th = np.interp(t, truth.t_s, truth.H_m)
    yaw = np.interp(t, truth.t_s, np.unwrap(truth.yaw_rad))
    grid = getattr(getattr(truth, "geometry", None), "grid", None)
    if grid is not None:  # the truth's yaw is true; the errors are split along the grid bearing
        yaw = yaw - grid.convergence_rad
    dE, dN, dH = enh_m[moving, 0] - te, enh_m[moving, 1] - tn, enh_m[moving, 2] - th
    c, s = np.cos(yaw), np.sin(yaw)
    sE, sN = sigma_enh_m[moving, 0], sigma_enh_m[moving, 1]
    cEN = None if cov_EN_m2 is None else np.asarray(cov_EN_m2, dtype=float)[moving]
    return TrackErrors(
        lateral_m=c * dE - s * dN, longitudinal_m=s * dE + c * dN, vertical_m=dH,
        sigma_lateral_m=lateral_sigma(sE, sN, yaw, cEN),
        # the along-track direction (sin psi, cos psi) is the right normal of the bearing psi - 90 deg
        sigma_longitudinal_m=lateral_sigma(sE, sN, yaw - 0.5 * np.pi, cEN),
        sigma_vertical_m=sigma_enh_m[moving, 2])
