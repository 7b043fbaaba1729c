"""Track quality per section: the standard deviation of a geometry parameter over fixed-length sections.

EN 13848-6 describes the quality of a stretch of track by the standard deviation of the
band-passed longitudinal level and alignment (and of cross level, gauge, twist) over sections of
fixed length, 200 m being the common choice. For a section with the valid samples x_1 .. x_n:

    SD = sqrt( (1/n) sum (x_i - mean)^2 )                                            (1)

(the population form, 1/n, as EN 13848-6 writes it). Sections are aligned on multiples of the
section length in chainage (0-200 m, 200-400 m, ...), each holding the stations with
``start <= s < end``. A section with fewer than ``min_fraction`` of its stations valid (NaN:
not measured, band-pass edge zones) has no SD (NaN), so a half-empty section at the end of a survey is
not mistaken for a quiet one.

References
----------
EN 13848-6:2014, 5 (standard deviation over a section as a track-quality figure);
shared/research/anchors.md 2.2 (the band-passed parameters); docs/track_geometry.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: default section length of EN 13848-6 style quality figures, m
SECTION_LENGTH_M = 200.0


@dataclass(frozen=True)
class SectionQuality:
    """Per-section figures of one parameter (arrays over the sections, SI).

    Attributes
    ----------
    start_m, end_m : section limits in chainage, m (start inclusive, end exclusive).
    count : valid samples in the section.
    expected : stations a full section holds (``length / step``), or the stations in it.
    mean : mean of the valid samples.
    std : standard deviation, Eq. (1); NaN when fewer than ``min_fraction`` are valid.
    """

    start_m: np.ndarray
    end_m: np.ndarray
    count: np.ndarray
    expected: np.ndarray
    mean: np.ndarray
    std: np.ndarray


def section_quality(chainage_m: np.ndarray, x: np.ndarray, length_m: float = SECTION_LENGTH_M,
                    min_fraction: float = 0.5, step_m: float | None = None) -> SectionQuality:
    """Standard deviation of ``x`` per chainage section, Eq. (1).

    Parameters
    ----------
    chainage_m : station chainage, increasing, m.
    x : parameter values at the stations (NaN: not available).
    length_m : section length, m (> 0).
    min_fraction : least share of valid stations for a section to get an SD (0..1).
    step_m : station step of a uniform grid: a full section then expects ``length_m / step_m``
        stations, so a section the survey only touches (a few stations at its end) gets no SD;
        None: a section expects the stations it holds.

    Returns
    -------
    SectionQuality over every section touched by ``chainage_m``, in chainage order.

    References
    ----------
    EN 13848-6:2014, 5.
    """
    s = np.asarray(chainage_m, dtype=float)
    v = np.asarray(x, dtype=float)
    if s.shape != v.shape or s.ndim != 1:
        raise ValueError(f"chainage and values must be 1-D of one length, got {s.shape} and {v.shape}")
    if not length_m > 0 or not np.isfinite(length_m):
        raise ValueError(f"section length must be a positive number of metres, got {length_m!r}")
    if not 0.0 <= min_fraction <= 1.0:
        raise ValueError(f"min_fraction must be within 0..1, got {min_fraction!r}")
    if s.size == 0:
        empty = np.zeros(0)
        return SectionQuality(empty, empty, np.zeros(0, int), np.zeros(0, int), empty, empty)
    k = np.floor(s / length_m).astype(np.int64)
    # s / length_m can round onto a section boundary that s has not reached (or past one it has):
    # a station belongs to the section whose reported start <= s < start + length_m
    k -= s < k * length_m
    k += s >= k * length_m + length_m
    k0 = int(k[0])
    idx = k - k0
    n_sec = int(idx[-1]) + 1
    ok = np.isfinite(v)
    expected = np.bincount(idx, minlength=n_sec)
    if step_m is not None:
        if not step_m > 0:
            raise ValueError(f"station step must be > 0, got {step_m!r}")
        expected = np.full(n_sec, int(round(length_m / step_m)))
    count = np.bincount(idx[ok], minlength=n_sec)
    total = np.bincount(idx[ok], weights=v[ok], minlength=n_sec)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
        # two-pass: deviations from each section's own mean (no cancellation of sum x^2 - n mean^2)
        dev = v[ok] - mean[idx[ok]]
        var = np.bincount(idx[ok], weights=dev * dev, minlength=n_sec) / count
    std = np.sqrt(var)
    std[(count == 0) | (count < min_fraction * expected)] = np.nan
    mean[count == 0] = np.nan
    start = (np.arange(n_sec) + k0) * length_m
    return SectionQuality(start_m=start, end_m=start + length_m, count=count, expected=expected,
                          mean=mean, std=std)


__all__ = ["SECTION_LENGTH_M", "SectionQuality", "section_quality"]
