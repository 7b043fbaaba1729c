"""Two surveys of one track compared: do they agree within their sigmas, and where did the track move?

Surveying the same track twice is how trolley systems are checked and how track movement is found:
the Swiss Trolley was validated by a forward and a backward run over 250 m, System7's approval
runs compare test runs with the machine turned round, and GeoTEC compares historical runs to see
the track deteriorate (shared/research/anchors.md sections 1.3, 1.4 and 4). Here the second track
is taken at the stations of the first: each station of track A is projected onto track B's
polyline (the foot of the perpendicular, so B's along-track error does not enter) and the
difference B - A is split across A's direction (positive to the right facing A's increasing
station, as ``lateral_dev`` of FORMATS.md section 2) and in height, with cant and gauge beside.

Each difference is judged against its own sigma, sqrt(sigma_A^2 + sigma_B^2): the two surveys'
errors are independent (their own IMU and odometer errors, their own fixes and station setups),
except what both share, the control network's coordinates and, with the same trolley, its
calibration (the prism lever arm, the cant sensor's zero), which cancel in the difference and
which neither sigma holds. A difference beyond ``limit`` sigmas (default 3) is either a
disagreement of the surveys (a blunder, a sigma too small) or, between surveys before and after
track work, a movement of the track that the surveys resolve.

The sigmas of neighbouring stations are strongly correlated (the error of a smoothed track varies
over tens of metres), so the stations are not independent samples: the RMS of difference/sigma
is reported but is not a chi-square test, and a run of stations beyond the limit is one finding,
reported as one stretch.

No paper section: this is the evaluation around Jiang 2017's smoothed track; the EN 13848-1
bands (``trolley.bands``) give the repeatability of the relative geometry per wavelength range.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from trolley.bands import BANDS, band
from trolley.trackgeometry import (GAP_STEPS, TrackInput, column_stats, gap_intervals, heading_from_positions,
                                   lateral_sigma)

#: |difference| / sigma beyond which a station is reported. Not 3: a 1.2 km track holds a few dozen
#: independent stretches in each of three quantities, and 3 sigma was passed somewhere in 15 of
#: 60 pairs of correct simulated surveys (RLG, FOG, MEMS, 20 pairs each), 4 sigma in 1
#: (benchmarks/bench_compare.py; docs/track_geometry.md, "Two surveys of one track")
DEFAULT_LIMIT = 4.0
#: a station of A farther than this from track B is not beside it (another track, a turnout's
#: other branch): the largest tamping slew or lift is a few centimetres
DEFAULT_MAX_OFFSET_M = 0.5


@dataclass
class Stretch:
    """A run of consecutive stations whose difference is beyond the limit.

    Attributes
    ----------
    quantity : "lateral", "vertical" or "cant".
    start_m, end_m : first and last station of the run (track A's internal station), m.
    max_abs_diff_m : the largest |B - A| in the run, m.
    max_abs_z : the largest |B - A| / sigma in the run.
    at_m : where the largest |B - A| / sigma is, m.
    stations : number of stations in the run.
    """

    quantity: str
    start_m: float
    end_m: float
    max_abs_diff_m: float
    max_abs_z: float
    at_m: float
    stations: int


@dataclass
class TrackDifference:
    """Track B minus track A at A's stations (NaN where B is not beside A).

    Attributes
    ----------
    station_m : track A's stations (its ``chainage_m``, the internal station), m.
    beside : True where B runs beside the station (the foot of the perpendicular lies on B, not
        inside a gap of B's stations, and is within ``max_offset_m``).
    lateral_m : horizontal difference across A's direction, + when B is to the right, m.
    vertical_m : height difference, + when B is higher, m.
    sigma_lateral_m, sigma_vertical_m : 1-sigma of the differences, sqrt(sigma_A^2 + sigma_B^2), m.
    cant_m, sigma_cant_m : cant difference and its 1-sigma (NaN where either cant or either cant
        sigma is not known), m.
    gauge_m : gauge difference (no sigma: track.csv has none for the gauge), m.
    """

    station_m: np.ndarray
    beside: np.ndarray
    lateral_m: np.ndarray
    vertical_m: np.ndarray
    sigma_lateral_m: np.ndarray
    sigma_vertical_m: np.ndarray
    cant_m: np.ndarray
    sigma_cant_m: np.ndarray
    gauge_m: np.ndarray

    def z(self, quantity: str) -> np.ndarray:
        """difference / its sigma of ``quantity`` ("lateral", "vertical", "cant")."""
        d, s = getattr(self, f"{quantity}_m"), getattr(self, f"sigma_{quantity}_m")
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(s > 0, d / s, np.nan)


@dataclass
class Comparison:
    """The comparison of two tracks (:func:`compare_tracks`).

    Attributes
    ----------
    difference : B - A at A's stations.
    limit : the |difference| / sigma beyond which a station counts as beyond.
    common_m : length of A's track beside which B runs, m.
    rms_m, max_abs_m : RMS and largest |B - A| per quantity (lateral, vertical, cant, gauge), m.
    rms_z : RMS of difference / sigma per quantity (lateral, vertical, cant); 1 for honest sigmas,
        but see the module's note on correlated stations.
    sigma_median_m, sigma_max_m : median and largest sigma of the difference per quantity, m:
        surveys agree within a large sigma too, and a survey whose fixes were rejected has one.
    beyond : number of stations beyond the limit per quantity.
    zero_sigma : number of stations per quantity whose difference is not zero but whose sigma is
        (both files give a zero sigma): not within any number of sigmas, so not agreeing.
    stretches : the runs of stations beyond the limit, in station order per quantity.
    band_rms_m : RMS of the band-passed lateral and vertical differences per EN 13848 band
        (``{"lateral": {"D1": ...}, ...}``; NaN where the common track is too short for the band),
        the repeatability of the relative geometry.
    """

    difference: TrackDifference
    limit: float
    common_m: float
    rms_m: dict[str, float]
    max_abs_m: dict[str, float]
    rms_z: dict[str, float]
    beyond: dict[str, int]
    sigma_median_m: dict[str, float] = field(default_factory=dict)
    sigma_max_m: dict[str, float] = field(default_factory=dict)
    stretches: list[Stretch] = field(default_factory=list)
    band_rms_m: dict[str, dict[str, float]] = field(default_factory=dict)
    zero_sigma: dict[str, int] = field(default_factory=dict)

    @property
    def agree(self) -> bool:
        """True when no station is beyond the limit in any quantity, nor differs against a zero sigma."""
        return not any(self.beyond.values()) and not any(self.zero_sigma.values())


def _foot_on_polyline(px: np.ndarray, py: np.ndarray, ex: np.ndarray, ey: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest point of the polyline (ex, ey) to each point (px, py).

    Returns (segment index k, fraction t in [0, 1] along segment k -> k + 1, True where the foot of
    the perpendicular falls beyond the polyline's ends). The nearest vertex (a k-d tree) and the
    two segments meeting there are tried: the track's curvature radius is thousands of stations,
    so the nearest point lies on one of them.
    """
    n = ex.size
    _, j = cKDTree(np.column_stack([ex, ey])).query(np.column_stack([px, py]))
    best_k = np.zeros(px.size, dtype=int)
    best_t = np.zeros(px.size)
    best_d2 = np.full(px.size, np.inf)
    raw_t = np.zeros(px.size)
    for k in (np.clip(j - 1, 0, n - 2), np.clip(j, 0, n - 2)):
        dx, dy = ex[k + 1] - ex[k], ey[k + 1] - ey[k]
        t = ((px - ex[k]) * dx + (py - ey[k]) * dy) / (dx * dx + dy * dy)
        tc = np.clip(t, 0.0, 1.0)
        d2 = (ex[k] + tc * dx - px) ** 2 + (ey[k] + tc * dy - py) ** 2
        better = d2 < best_d2
        best_k[better], best_t[better], best_d2[better], raw_t[better] = k[better], tc[better], d2[better], t[better]
    # a foot more than a thousandth of a segment beyond an end is off the polyline
    outside = ((best_k == 0) & (raw_t < -1e-3)) | ((best_k == n - 2) & (raw_t > 1.0 + 1e-3))
    return best_k, best_t, outside


def _at_foot(x: np.ndarray | None, k: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``x`` of track B interpolated at the feet (segment k, fraction t); NaN for None."""
    if x is None:
        return np.full(k.size, np.nan)
    x = np.asarray(x, dtype=float)
    return x[k] * (1.0 - t) + x[k + 1] * t


def track_difference(a: TrackInput, b: TrackInput, max_offset_m: float = DEFAULT_MAX_OFFSET_M) -> TrackDifference:
    """Track B minus track A at A's stations, across A's direction and in height, with sigmas.

    Parameters
    ----------
    a, b : the two tracks (``TrackInput``, e.g. from ``survey.track_reader.read_track_file``), on
        the same grid (E, N, H); B may run either way and need not share A's stations.
    max_offset_m : a station of A farther than this from B is not compared.

    Returns
    -------
    TrackDifference. B's values are interpolated linearly along its polyline at the foot of the
    perpendicular from A's station (the chord's sag at 0.625 m stations on a 300 m radius is
    0.16 um); B's variances likewise. Nothing is interpolated across a gap of B's stations (an
    interval longer than ``trackgeometry.GAP_STEPS`` of its median step, as the survey sheet):
    a station of A whose foot falls inside one is not beside B. Where B runs the other way
    (its increasing station against A's), B's cant is turned to A's direction (FORMATS.md: + when
    the left rail is higher facing increasing chainage). The lateral sigma of each track is its
    horizontal covariance projected on A's right normal (``trackgeometry.lateral_sigma``; a track
    without ``cov_EN_m2`` takes it as 0).
    """
    if b.E_m.size < 2:
        raise ValueError("track B needs at least two stations")
    k, t, outside = _foot_on_polyline(a.E_m, a.N_m, b.E_m, b.N_m)
    psi = heading_from_positions(a.E_m, a.N_m)
    c, s = np.cos(psi), np.sin(psi)
    dE = _at_foot(b.E_m, k, t) - a.E_m
    dN = _at_foot(b.N_m, k, t) - a.N_m
    sb = np.asarray(b.chainage_m, dtype=float)
    gap = gap_intervals(sb, float(np.median(np.diff(sb))), GAP_STEPS)[k] & (t > 1e-9) & (t < 1.0 - 1e-9)
    beside = ~outside & ~gap & (np.hypot(dE, dN) <= max_offset_m)
    # +1 where B's segment at the foot runs along A's direction (psi is a bearing: forward (sin, cos))
    along = np.where(s * (b.E_m[k + 1] - b.E_m[k]) + c * (b.N_m[k + 1] - b.N_m[k]) < 0.0, -1.0, 1.0)

    def var_b(sigma):
        return _at_foot(np.asarray(sigma, dtype=float) ** 2, k, t)

    cov_b = None if b.cov_EN_m2 is None else _at_foot(b.cov_EN_m2, k, t)
    sig_lat_b = lateral_sigma(np.sqrt(var_b(b.sigma_E_m)), np.sqrt(var_b(b.sigma_N_m)), psi, cov_b)
    sig_lat_a = lateral_sigma(a.sigma_E_m, a.sigma_N_m, psi, a.cov_EN_m2)
    cant_var_a = np.full(a.E_m.size, np.nan) if a.sigma_cant_m is None else np.asarray(a.sigma_cant_m) ** 2
    cant_var_b = np.full(a.E_m.size, np.nan) if b.sigma_cant_m is None else var_b(b.sigma_cant_m)

    def only_beside(x):
        return np.where(beside, x, np.nan)

    return TrackDifference(
        station_m=np.asarray(a.chainage_m, dtype=float).copy(), beside=beside,
        lateral_m=only_beside(c * dE - s * dN),
        vertical_m=only_beside(_at_foot(b.H_m, k, t) - a.H_m),
        sigma_lateral_m=only_beside(np.hypot(sig_lat_a, sig_lat_b)),
        sigma_vertical_m=only_beside(np.sqrt(np.asarray(a.sigma_H_m) ** 2 + var_b(b.sigma_H_m))),
        cant_m=only_beside(along * _at_foot(b.cant_m, k, t) - a.cant_m),
        sigma_cant_m=only_beside(np.sqrt(cant_var_a + cant_var_b)),
        gauge_m=only_beside(_at_foot(b.gauge_m, k, t) - a.gauge_m))


def stretches_beyond(station_m: np.ndarray, diff_m: np.ndarray, z: np.ndarray, limit: float,
                     quantity: str) -> list[Stretch]:
    """The runs of consecutive stations with |z| > ``limit`` (NaN ends a run)."""
    over = np.abs(np.nan_to_num(z, nan=0.0)) > limit
    edges = np.flatnonzero(np.diff(np.r_[0, over.astype(np.int8), 0]))
    out = []
    # one item per run (a handful), not per station
    for i0, i1 in zip(edges[::2].tolist(), edges[1::2].tolist()):
        zz = np.abs(z[i0:i1])
        j = i0 + int(np.argmax(zz))
        out.append(Stretch(quantity, float(station_m[i0]), float(station_m[i1 - 1]),
                           float(np.max(np.abs(diff_m[i0:i1]))), float(zz.max()), float(station_m[j]), i1 - i0))
    return out


def _rms(x: np.ndarray) -> float:
    """RMS of the finite values (NaN when none): ``trackgeometry.column_stats``."""
    return column_stats("", x).rms


def _max_abs(x: np.ndarray) -> float:
    """Largest |value| of the finite values (NaN when none)."""
    st = column_stats("", x)
    return max(abs(st.minimum), abs(st.maximum))


def compare_tracks(a: TrackInput, b: TrackInput, limit: float = DEFAULT_LIMIT,
                   max_offset_m: float = DEFAULT_MAX_OFFSET_M) -> Comparison:
    """Compare two surveys of one track: differences, their sigmas, stretches beyond ``limit``.

    Parameters
    ----------
    a, b : the two tracks; A gives the stations and the direction (lateral + to its right).
    limit : |difference| / sigma beyond which a station is reported (> 0).
    max_offset_m : a station of A farther than this from B is not compared.

    Returns
    -------
    Comparison.

    Raises
    ------
    ValueError when no station of A has track B beside it.
    """
    if not limit > 0:
        raise ValueError(f"limit must be > 0, got {limit!r}")
    d = track_difference(a, b, max_offset_m)
    if not d.beside.any():
        raise ValueError(f"the two tracks do not run beside each other (no station of the first within "
                         f"{max_offset_m:g} m of the second): not surveys of one track")
    s = d.station_m
    steps = np.diff(s)
    # the length of A beside B: a step counts when both its stations are beside
    common = float(np.sum(steps[d.beside[1:] & d.beside[:-1]]))
    quantities = ("lateral", "vertical", "cant")
    rms = {q: _rms(getattr(d, f"{q}_m")) for q in (*quantities, "gauge")}
    mx = {q: _max_abs(getattr(d, f"{q}_m")) for q in (*quantities, "gauge")}
    rms_z, beyond, stretches, zero_sigma = {}, {}, [], {}
    for q in quantities:
        z = d.z(q)
        zero_sigma[q] = int(np.sum((getattr(d, f"sigma_{q}_m") == 0.0) & (np.abs(getattr(d, f"{q}_m")) > 0.0)))
        rms_z[q] = _rms(z)
        beyond[q] = int(np.sum(np.abs(np.nan_to_num(z, nan=0.0)) > limit))
        stretches += stretches_beyond(s, getattr(d, f"{q}_m"), z, limit, q)
    step = float(np.median(steps)) if steps.size else float("nan")
    uniform = steps.size > 0 and np.allclose(steps, step, rtol=1e-3, atol=0.0)
    bands = {}
    for q in ("lateral", "vertical"):
        x = getattr(d, f"{q}_m")
        bands[q] = {name: _rms(band(x, step, name, settled=True)) if uniform else float("nan") for name in BANDS}
    sig = {q: getattr(d, f"sigma_{q}_m") for q in quantities}
    med = {q: float(np.nanmedian(v)) if np.isfinite(v).any() else float("nan") for q, v in sig.items()}
    return Comparison(d, float(limit), common, rms, mx, rms_z, beyond, med, {q: _max_abs(v) for q, v in sig.items()},
                      stretches, bands, zero_sigma)
