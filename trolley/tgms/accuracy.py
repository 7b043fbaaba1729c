"""Accuracy of TGMS irregularities against the truth of a synthetic recording.

Two comparisons, both after the same zero-phase band-pass of measurement and truth:

* **as reported**: ``irregularities.csv`` (stations from the odometry) against the truth at the
  same stations; this includes the odometry's station error;
* **registered**: every camera frame placed at its TRUE station (from the truth's t(s)) before
  resampling; this isolates the measurement error from the positioning error, as a comparison with
  a reference survey aligned on the same stations would.

The 95 % intervals (1.96 sigma of the filter/fit covariance) are checked against the unfiltered
truth (after removing the mean error, which the band-pass removes anyway).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trolley.bands import bandpass_wavelength
from trolley.tgms.irregularities import Irregularities, resample_irregularities

NAMES = Irregularities.NAMES


@dataclass
class Accuracy:
    """Error statistics per irregularity (mm): std and max |error| after band-pass, for the output
    as reported and registered on the true stations; coverage of the 95 % interval (fraction), the
    median reported 1-sigma and the std of the unfiltered error (mean removed) it should match."""

    std_mm: dict
    max_mm: dict
    std_registered_mm: dict
    max_registered_mm: dict
    coverage95: dict
    n_points: int
    sigma_median_mm: dict | None = None
    error_std_unfiltered_mm: dict | None = None


def _truth_on(truth: dict, s: np.ndarray, name: str) -> np.ndarray:
    return np.interp(s, truth["s_m"], truth[f"{name}_mm"]) * 1e-3


def _band_errors(grid: Irregularities, truth: dict, step_m: float, band: tuple[float, float], trim_m: float):
    inside = (grid.s_m >= truth["s_m"][0] + trim_m) & (grid.s_m <= truth["s_m"][-1] - trim_m)
    out = {}
    for name in NAMES:
        meas = getattr(grid, f"{name}_m")
        tru = _truth_on(truth, grid.s_m, name)
        e = bandpass_wavelength(meas, step_m, *band) - bandpass_wavelength(np.where(np.isfinite(meas), tru, np.nan), step_m, *band)
        e = np.where(inside, e, np.nan)
        out[name] = e
    return out


def accuracy(frames: Irregularities, truth: dict, frame_t_s: np.ndarray, step_m: float = 0.25,
             band: tuple[float, float] = (3.0, 25.0), trim_m: float = 25.0,
             laser_offset_m=0.0) -> Accuracy:
    """Band-passed error statistics of a processing result against the truth.

    Parameters
    ----------
    frames : per-frame irregularities (``TgmsResult.frames``).
    truth : columns of truth.csv (s_m, *_mm, t_s, ...).
    frame_t_s : camera frame times (for the registered comparison).
    laser_offset_m : per-frame station offset of the laser cut ahead of the IMU
        (``TgmsResult.laser_offset_m``), added to the IMU's true station when registering.
    step_m : output grid step.
    band : (short, long) wavelengths of the band-pass, m.
    trim_m : stations this close to the ends of the ride are left out: the band-pass edge
        transients of the (large, long-wave) unfiltered error reach about one long wavelength in.

    Returns
    -------
    Accuracy
    """
    grid = resample_irregularities(frames, step_m)
    e = _band_errors(grid, truth, step_m, band, trim_m)
    # registered: the frames at their true stations
    s_true = np.interp(frame_t_s, truth["t_s"], truth["s_m"], left=np.nan, right=np.nan) + laser_offset_m
    reg = Irregularities(s_true, *(getattr(frames, f) for f in (
        "gauge_variation_m", "cross_level_m", "alignment_m", "vertical_profile_m",
        "sigma_gauge_variation_m", "sigma_cross_level_m", "sigma_alignment_m", "sigma_vertical_profile_m")))
    reg = Irregularities(np.where(np.isfinite(frames.s_m), s_true, np.nan), *list(vars(reg).values())[1:])
    greg = resample_irregularities(reg, step_m)
    er = _band_errors(greg, truth, step_m, band, trim_m)
    cov, sig_med, err_unf = {}, {}, {}
    inside = (greg.s_m >= truth["s_m"][0] + trim_m) & (greg.s_m <= truth["s_m"][-1] - trim_m)
    for name in NAMES:
        d = getattr(greg, f"{name}_m") - _truth_on(truth, greg.s_m, name)
        sg = getattr(greg, f"sigma_{name}_m")
        ok = inside & np.isfinite(d) & np.isfinite(sg)
        if ok.sum() > 10:
            dd = d[ok] - np.mean(d[ok])
            cov[name] = float(np.mean(np.abs(dd) <= 1.96 * sg[ok]))
            sig_med[name] = float(np.median(sg[ok])) * 1e3
            err_unf[name] = float(np.std(dd)) * 1e3
        else:
            cov[name] = sig_med[name] = err_unf[name] = float("nan")

    def stats(err, f):
        return {k: float(f(np.abs(v[np.isfinite(v)]))) * 1e3 if np.isfinite(v).any() else float("nan")
                for k, v in err.items()}

    return Accuracy(std_mm={k: float(np.nanstd(v)) * 1e3 for k, v in e.items()}, max_mm=stats(e, np.max),
                    std_registered_mm={k: float(np.nanstd(v)) * 1e3 for k, v in er.items()},
                    max_registered_mm=stats(er, np.max), coverage95=cov,
                    n_points=int(np.isfinite(e["gauge_variation"]).sum()),
                    sigma_median_mm=sig_med, error_std_unfiltered_mm=err_unf)
