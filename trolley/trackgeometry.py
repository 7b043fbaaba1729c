"""Track geometry parameters of a surveyed track on a uniform chainage grid.

From the processed track (FORMATS.md section 2: smoothed E, N, H with sigmas, deviations from
design, gauge, cant) and, where available, the design geometry at the same chainages, this
computes the survey-sheet parameters, all vectorised, all in SI (m, m/m):

* absolute: lateral / vertical deviation, the corrections a tamping or slab-adjustment crew
  applies (slew = -lateral deviation, lift = -vertical deviation) and their 1-sigma;
* relative: gauge, gauge deviation and gauge change rate; cant, design cant and cant
  deviation; twist over a base; horizontal and vertical versines on a symmetric chord (measured,
  design and their difference); the long-chord checks of ballastless high-speed track
  (30 m chord / 5 m, 300 m chord / 150 m); EN 13848 D1/D2/D3 alignment and longitudinal level
  (zero-phase band-pass of the deviations, :mod:`trolley.bands`).

Conventions (defaults follow FORMATS.md; each is a :class:`GeometryConfig` setting, nothing is
flipped silently; see docs/track_geometry.md):

* lateral quantities (lateral deviation, slew, horizontal versines, long-chord lateral values,
  alignment bands) are positive to the RIGHT facing increasing chainage (``lateral_sign="right"``);
* cant is positive when the LEFT rail is higher (``cant_sign="left_high"``), i.e. the FRD roll;
* versines are ``v(s) = z(s) - (z(s - L/2) + z(s + L/2)) / 2`` (``versine_sign="centre_minus_chord"``,
  anchors.md 2.4), with z the lateral coordinate (horizontal) or the height (vertical): a crest
  has a positive vertical versine, a right-hand curve a negative horizontal one;
* twist and gauge change rate are backward differences ``x(s) - x(s - b)`` over the base b;
  ``twist_dev`` is the twist of the cant deviation (measured twist less the design twist of
  cant ramps).

Values that need samples outside the surveyed stretch (ends of chords, bases, filters) are NaN.

References
----------
EN 13848-1 (parameters, D bands); TB 10754 / TB 10601 long-chord checks as used in Chinese
ballastless-track practice (shared/research/anchors.md 2.2, 2.4); protocols.md 6.1 (columns).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trolley.bands import BANDS, band

_LATERAL_SIGNS = {"right": 1.0, "left": -1.0}
_CANT_SIGNS = {"left_high": 1.0, "right_high": -1.0}
_VERSINE_SIGNS = {"centre_minus_chord": 1.0, "chord_minus_centre": -1.0}


@dataclass(frozen=True)
class GeometryConfig:
    """Settings of the geometry parameters (lengths in m).

    Attributes
    ----------
    twist_base_m : base of the twist (3 m default; 6.25 m also common).
    gauge_rate_base_m : base of the gauge change rate.
    versine_chord_m : symmetric chord of the horizontal and vertical versines.
    long_chords_m : (chord, spacing) pairs of the long-chord checks.
    bands : EN 13848 bands to compute (keys of :data:`trolley.bands.BANDS`).
    nominal_gauge_m : nominal gauge (gauge deviation = gauge - nominal).
    rail_spacing_m : rail centre distance (cant = rail_spacing * sin(roll)).
    lateral_sign, cant_sign, versine_sign : sign conventions (module docstring).
    """

    twist_base_m: float = 3.0
    gauge_rate_base_m: float = 3.0
    versine_chord_m: float = 10.0
    long_chords_m: tuple[tuple[float, float], ...] = ((30.0, 5.0), (300.0, 150.0))
    bands: tuple[str, ...] = ("D1", "D2", "D3")
    nominal_gauge_m: float = 1.435
    rail_spacing_m: float = 1.500
    lateral_sign: str = "right"
    cant_sign: str = "left_high"
    versine_sign: str = "centre_minus_chord"

    def __post_init__(self) -> None:
        for name, table in (("lateral_sign", _LATERAL_SIGNS), ("cant_sign", _CANT_SIGNS),
                            ("versine_sign", _VERSINE_SIGNS)):
            if getattr(self, name) not in table:
                raise ValueError(f"{name} must be one of {sorted(table)}, got {getattr(self, name)!r}")
        for name in ("twist_base_m", "gauge_rate_base_m", "versine_chord_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")
        for chord, spacing in self.long_chords_m:
            if not (0 < spacing < chord):
                raise ValueError(f"long chord {chord} m with spacing {spacing} m: need 0 < spacing < chord")
        for b in self.bands:
            if b not in BANDS:
                raise ValueError(f"unknown band {b!r}")


@dataclass
class TrackInput:
    """A processed track on stations (arrays of one length; NaN where not available).

    Attributes
    ----------
    chainage_m : station chainage, strictly increasing, m.
    E_m, N_m, H_m : smoothed track reference point, m.
    sigma_E_m, sigma_N_m, sigma_H_m : its 1-sigma, m.
    lateral_dev_m : horizontal offset from design, positive right (FORMATS.md), m.
    vertical_dev_m : height above design, m.
    gauge_m : measured full gauge, m.
    cant_m : measured cant, positive when the left rail is higher, m.
    design_E_m, design_N_m, design_H_m, design_cant_m : design at the stations (cant + left
        high), m; None without a design.
    cov_EN_m2 : covariance of E and N, m^2 (with the sigmas the whole horizontal covariance; E
        and N errors are correlated, |rho| 0.29 median for the RLG, 0.71 for MEMS); None: not
        known, taken as 0 by the lateral sigma.
    sigma_cant_m : 1-sigma of the cant, m (the engine's: the rail spacing times the roll sigma,
        the level error the re-levelling at the stops leaves, accelerometer bias / g and the
        residual roll mounting, one error for the whole survey that cancels in twist, and the
        gyros' roll drift between the levelled stops, which does not). None: not known.
    """

    chainage_m: np.ndarray
    E_m: np.ndarray
    N_m: np.ndarray
    H_m: np.ndarray
    sigma_E_m: np.ndarray
    sigma_N_m: np.ndarray
    sigma_H_m: np.ndarray
    lateral_dev_m: np.ndarray
    vertical_dev_m: np.ndarray
    gauge_m: np.ndarray
    cant_m: np.ndarray
    design_E_m: np.ndarray | None = None
    design_N_m: np.ndarray | None = None
    design_H_m: np.ndarray | None = None
    design_cant_m: np.ndarray | None = None
    cov_EN_m2: np.ndarray | None = None
    sigma_cant_m: np.ndarray | None = None


@dataclass
class TrackGeometry:
    """Geometry parameters per station.

    Attributes
    ----------
    chainage_m : uniform station grid, m.
    step_m : grid step, m.
    columns : parameter name -> array (SI; names carry the unit: ``_m`` or ``_m_per_m``), in
        survey-sheet order. Names are listed by :func:`column_names`.
    config : the settings used.
    resampled : True when the input chainage was not uniform and was interpolated onto the grid.
    gaps_m : input intervals longer than :data:`GAP_STEPS` steps, (from, to) in m: the grid
        stations inside them are empty (NaN), not interpolated.
    """

    chainage_m: np.ndarray
    step_m: float
    columns: dict[str, np.ndarray]
    config: GeometryConfig
    resampled: bool = False
    gaps_m: tuple = ()


def long_chord_name(chord_m: float, spacing_m: float, direction: str) -> str:
    """Column name of a long-chord check, e.g. ``chord30_5_lat_m``."""
    return f"chord{chord_m:g}_{spacing_m:g}_{direction}_m".replace(".", "p")


def band_source(key: str) -> str | None:
    """The deviation column a band column is filtered from ("align_D1_m" -> "lateral_dev_m",
    "level_D3_m" -> "vertical_dev_m"); None for other columns."""
    if key.startswith("align_D"):
        return "lateral_dev_m"
    if key.startswith("level_D"):
        return "vertical_dev_m"
    return None


def column_names(config: GeometryConfig) -> list[str]:
    """Names of the :attr:`TrackGeometry.columns` for a configuration, in sheet order."""
    names = ["E_m", "N_m", "H_m", "sigma_E_m", "sigma_N_m", "sigma_H_m",
             "design_E_m", "design_N_m", "design_H_m",
             "lateral_dev_m", "vertical_dev_m", "sigma_lateral_m", "sigma_vertical_m",
             "slew_m", "lift_m",
             "gauge_m", "gauge_dev_m", "gauge_rate_m_per_m",
             "cant_m", "sigma_cant_m", "design_cant_m", "cant_dev_m", "twist_m", "twist_rate_m_per_m", "twist_dev_m",
             "versine_h_m", "design_versine_h_m", "versine_h_dev_m",
             "versine_v_m", "design_versine_v_m", "versine_v_dev_m"]
    for chord, spacing in config.long_chords_m:
        names += [long_chord_name(chord, spacing, "lat"), long_chord_name(chord, spacing, "vert")]
    names += [f"align_{b}_m" for b in config.bands] + [f"level_{b}_m" for b in config.bands]
    return names


def shifted(x: np.ndarray, d_samples: float, cubic: bool = False) -> np.ndarray:
    """``x`` read ``d_samples`` (may be fractional) ahead on its grid: y[i] = x(i + d).

    A fractional shift is read by linear interpolation between samples, or with ``cubic`` by
    4-point Lagrange interpolation, exact for polynomials up to degree 3: linear interpolation
    between stations 0.625 m apart reads a circular arc t (1 - t) step^2 / 2R inside its chord,
    which biased a 5.3 m chord's versine on R = 600 m by 0.059 mm. Cubic is for smooth
    geometry (versines); differences over a base (twist, gauge rate) stay linear, because
    cubic interpolation overshoots a step (a 1.5 mm cant error over 1 m read 1.62 mm of twist).
    Where one of the cubic's outer points is missing (a record end or a gap) it is quadratic on
    the three that exist, and linear where only the two neighbours do. NaN where i + d falls
    outside the record.
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    i0 = int(np.floor(d_samples))
    frac = d_samples - i0
    if abs(frac) < 1e-9:
        frac, i0 = 0.0, int(round(d_samples))
    elif abs(frac - 1.0) < 1e-9:
        frac, i0 = 0.0, i0 + 1
    out = np.full(n, np.nan)
    lo, hi = max(0, -i0), min(n, n - i0 - (1 if frac else 0))
    if hi <= lo:
        return out
    if not frac:
        out[lo:hi] = x[lo + i0:hi + i0]
        return out
    if not cubic:
        out[lo:hi] = (1.0 - frac) * x[lo + i0:hi + i0] + frac * x[lo + i0 + 1:hi + i0 + 1]
        return out
    # the four samples around each reading, NaN beyond the record
    xp = np.concatenate(([np.nan], x, [np.nan, np.nan]))
    j = np.arange(lo, hi) + i0 + 1                      # index of x[i + i0] in xp
    xm, x0, x1, x2 = xp[j - 1], xp[j], xp[j + 1], xp[j + 2]
    f = frac
    readings = (
        -f * (f - 1) * (f - 2) / 6 * xm + (f + 1) * (f - 1) * (f - 2) / 2 * x0
        - (f + 1) * f * (f - 2) / 2 * x1 + (f + 1) * f * (f - 1) / 6 * x2,     # cubic
        (f - 1) * (f - 2) / 2 * x0 - f * (f - 2) * x1 + f * (f - 1) / 2 * x2,  # quadratic ahead
        f * (f - 1) / 2 * xm + (1 - f * f) * x0 + (f + 1) * f / 2 * x1,      # quadratic behind
        (1.0 - f) * x0 + f * x1,                                              # linear
    )
    y = readings[-1]
    for r in readings[-2::-1]:
        y = np.where(np.isfinite(r), r, y)
    out[lo:hi] = y
    return out


def backward_difference(x: np.ndarray, base_m: float, step_m: float) -> np.ndarray:
    """``x(s) - x(s - base)`` on a uniform grid (twist, gauge change)."""
    return np.asarray(x, dtype=float) - shifted(x, -base_m / step_m)


def versine(z: np.ndarray, chord_m: float, step_m: float) -> np.ndarray:
    """Symmetric mid-chord versine ``z(s) - (z(s - L/2) + z(s + L/2)) / 2`` of a profile.

    Parameters
    ----------
    z : profile on a uniform grid (heights, or lateral offsets), m.
    chord_m : chord length L, m.
    step_m : grid step, m.

    Returns
    -------
    v : versine, m (NaN within L/2 of the ends). For a circle of radius R sampled along its
        arc, ``v = -R (1 - cos(L / 2R)) ~ -L^2 / 8R`` on the outward-positive side.

    References
    ----------
    shared/research/anchors.md 2.4; transfer function ``1 - cos(pi L / lambda)``.
    """
    h = 0.5 * chord_m / step_m
    z = np.asarray(z, dtype=float)
    return z - 0.5 * (shifted(z, -h, cubic=True) + shifted(z, h, cubic=True))


def horizontal_versine(E_m: np.ndarray, N_m: np.ndarray, chord_m: float, step_m: float) -> np.ndarray:
    """Offset of each station from the chord joining the stations L/2 behind and ahead.

    Parameters
    ----------
    E_m, N_m : plan positions on a uniform chainage grid, m.
    chord_m, step_m : chord length and grid step, m.

    Returns
    -------
    v : signed offset, m, positive when the station lies to the RIGHT of the chord (facing
        increasing chainage): a right-hand curve gives ``-(R - sqrt(R^2 - c^2/4))``, about
        ``-c^2 / 8R`` with c the straight chord length.
    """
    h = 0.5 * chord_m / step_m
    Ea, Na = shifted(E_m, -h, cubic=True), shifted(N_m, -h, cubic=True)
    Eb, Nb = shifted(E_m, h, cubic=True), shifted(N_m, h, cubic=True)
    dE, dN = Eb - Ea, Nb - Na
    length = np.hypot(dE, dN)
    with np.errstate(invalid="ignore", divide="ignore"):
        # right normal of direction (dE, dN) in an E-right, N-up grid is (dN, -dE)
        return ((np.asarray(E_m) - Ea) * dN - (np.asarray(N_m) - Na) * dE) / length


def long_chord_check(dev_m: np.ndarray, chord_m: float, spacing_m: float, step_m: float) -> np.ndarray:
    """Long-chord check of ballastless track (30 m / 5 m, 300 m / 150 m) on the deviations.

    For the chord of length B centred on each station, the deviations d = measured - design at
    the points 0, p, 2p, ..., B along it are referred to the straight line through the deviations
    at the two chord ends (r_k = d_k - l_k: the difference between measured and designed offset
    from the chord). The value is the difference r_{k+1} - r_k of consecutive points p apart
    with the largest magnitude (sign kept).

    Parameters
    ----------
    dev_m : lateral or vertical deviation from design on a uniform grid, m.
    chord_m, spacing_m : chord B and point spacing p, m (B / p rounded to an integer).
    step_m : grid step, m.

    Returns
    -------
    value : m, NaN where the chord leaves the record. With B = 2p (the 300 m / 150 m check) it
        is +-(mid-chord versine of the deviations on chord B).

    References
    ----------
    shared/research/anchors.md 2.2 (TB 10754 / TB 10601 practice; unverified text).
    """
    k_max = int(round(chord_m / spacing_m))
    p = chord_m / k_max
    d = np.asarray(dev_m, dtype=float)
    pts = np.stack([shifted(d, (k * p - 0.5 * chord_m) / step_m) for k in range(k_max + 1)])
    frac = (np.arange(k_max + 1) / k_max)[:, None]
    r = pts - (pts[0] + (pts[-1] - pts[0]) * frac)
    diffs = np.diff(r, axis=0)
    with np.errstate(invalid="ignore"):
        pick = np.argmax(np.where(np.isnan(diffs), -1.0, np.abs(diffs)), axis=0)
    out = np.take_along_axis(diffs, pick[None, :], axis=0)[0]
    out[np.isnan(diffs).any(axis=0)] = np.nan
    return out


def lateral_sigma(sigma_E_m, sigma_N_m, heading_rad, cov_EN_m2=None) -> np.ndarray:
    """1-sigma of the lateral position from the horizontal covariance.

    The lateral direction is the right normal of the track, (cos psi, -sin psi) in (E, N) for a
    grid bearing psi clockwise from north, so ``sigma_lat^2 = cos^2 psi sigma_E^2 +
    sin^2 psi sigma_N^2 - 2 sin psi cos psi cov_EN``. Without ``cov_EN_m2`` (a track.csv of
    before 2026-11-26) the covariance is taken as 0: over 64 simulated RLG surveys that made the
    lateral sigma 13 % too large, over MEMS surveys 12 % too small.
    """
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    var = (c * sigma_E_m) ** 2 + (s * sigma_N_m) ** 2
    if cov_EN_m2 is not None:
        var = var - 2.0 * s * c * np.asarray(cov_EN_m2, dtype=float)
    return np.sqrt(np.maximum(var, 0.0))


def heading_from_positions(E_m: np.ndarray, N_m: np.ndarray) -> np.ndarray:
    """Grid bearing (clockwise from north) of a polyline, by central differences."""
    return np.arctan2(np.gradient(E_m), np.gradient(N_m))


def uniform_grid(chainage_m: np.ndarray, rtol: float = 1e-3) -> tuple[np.ndarray, float, bool]:
    """The uniform grid a station list lies on (or should be resampled to).

    Returns
    -------
    grid, step_m, resampled : the grid; its step (median spacing); True when the input spacing
        varies by more than ``rtol`` of the step and values must be interpolated onto the grid.
    """
    s = np.asarray(chainage_m, dtype=float)
    if s.size < 2 or not np.all(np.diff(s) > 0):
        raise ValueError("chainage must be strictly increasing with at least two stations")
    d = np.diff(s)
    step = float(np.median(d))
    if np.max(np.abs(d - step)) <= rtol * step:
        return s.copy(), step, False
    n = int(np.floor((s[-1] - s[0]) / step + 1e-9)) + 1
    return s[0] + step * np.arange(n), step, True


#: an input interval longer than this many grid steps is a gap: nothing is interpolated across it
#: (one missing station is bridged, as a survey sheet conventionally does; two are not)
GAP_STEPS = 2.0


def chainage_gaps(chainage_m: np.ndarray, step_m: float, gap_steps: float = GAP_STEPS) -> list[tuple[float, float]]:
    """The intervals between consecutive stations longer than ``gap_steps`` grid steps, as
    (last station before, first station after) pairs, m."""
    s = np.asarray(chainage_m, dtype=float)
    i = np.flatnonzero(gap_intervals(s, step_m, gap_steps))
    return [(float(s[k]), float(s[k + 1])) for k in i]


def gap_intervals(s: np.ndarray, step_m: float, gap_steps: float = GAP_STEPS) -> np.ndarray:
    """True for each interval between consecutive stations longer than ``gap_steps`` steps."""
    return np.diff(s) > gap_steps * step_m * (1.0 + 1e-9)


def _resample(grid: np.ndarray, s: np.ndarray, x: np.ndarray | None, outside: np.ndarray) -> np.ndarray | None:
    if x is None:
        return None
    out = np.interp(grid, s, np.asarray(x, dtype=float))
    out[outside] = np.nan
    return out


def track_geometry(track: TrackInput, config: GeometryConfig = GeometryConfig()) -> TrackGeometry:
    """All survey-sheet geometry parameters of a track.

    Parameters
    ----------
    track : TrackInput, stations (uniform chainage; resampled linearly when not).
    config : GeometryConfig.

    Returns
    -------
    TrackGeometry
        Columns as listed by :func:`column_names`; design-dependent ones are NaN without a
        design (alignment/level bands, versine deviations and long chords need the deviations).
    """
    grid, step, resampled = uniform_grid(track.chainage_m)
    s = np.asarray(track.chainage_m, dtype=float)
    fields = ("E_m", "N_m", "H_m", "sigma_E_m", "sigma_N_m", "sigma_H_m", "lateral_dev_m",
              "vertical_dev_m", "gauge_m", "cant_m", "design_E_m", "design_N_m", "design_H_m",
              "design_cant_m", "cov_EN_m2", "sigma_cant_m")
    gaps = chainage_gaps(s, step) if resampled else []
    if resampled:
        # grid stations strictly inside a gap have no measurement: empty, never a straight line
        # (each grid station's input interval by one searchsorted, not a pass per gap)
        k = np.clip(np.searchsorted(s, grid, side="right") - 1, 0, s.size - 2)
        in_gap = gap_intervals(s, step)[k] & (grid > s[k] + 1e-9 * step) & (grid < s[k + 1] - 1e-9 * step)
        vals = {f: _resample(grid, s, getattr(track, f), in_gap) for f in fields}
    else:
        vals = {f: (None if getattr(track, f) is None else np.asarray(getattr(track, f), dtype=float))
                for f in fields}
    n = grid.size
    nan = np.full(n, np.nan)
    lat_sign = _LATERAL_SIGNS[config.lateral_sign]
    cant_sign = _CANT_SIGNS[config.cant_sign]
    v_sign = _VERSINE_SIGNS[config.versine_sign]
    has_design = vals["design_E_m"] is not None and vals["design_N_m"] is not None

    E, N, H = vals["E_m"], vals["N_m"], vals["H_m"]
    lat = vals["lateral_dev_m"]          # + right, as in track.csv
    vert = vals["vertical_dev_m"]
    dE = vals["design_E_m"] if has_design else nan
    dN = vals["design_N_m"] if has_design else nan
    dH = vals["design_H_m"] if vals["design_H_m"] is not None else nan
    heading = heading_from_positions(dE, dN) if has_design else heading_from_positions(E, N)

    c: dict[str, np.ndarray] = {}
    c["E_m"], c["N_m"], c["H_m"] = E, N, H
    c["sigma_E_m"], c["sigma_N_m"], c["sigma_H_m"] = vals["sigma_E_m"], vals["sigma_N_m"], vals["sigma_H_m"]
    c["design_E_m"], c["design_N_m"], c["design_H_m"] = dE, dN, dH
    c["lateral_dev_m"] = lat_sign * lat
    c["vertical_dev_m"] = vert
    c["sigma_lateral_m"] = lateral_sigma(vals["sigma_E_m"], vals["sigma_N_m"], heading, vals["cov_EN_m2"])
    c["sigma_vertical_m"] = vals["sigma_H_m"]
    c["slew_m"] = -c["lateral_dev_m"]
    c["lift_m"] = -vert

    gauge = vals["gauge_m"]
    c["gauge_m"] = gauge
    c["gauge_dev_m"] = gauge - config.nominal_gauge_m
    c["gauge_rate_m_per_m"] = backward_difference(gauge, config.gauge_rate_base_m, step) / config.gauge_rate_base_m

    cant = cant_sign * vals["cant_m"]
    design_cant = cant_sign * vals["design_cant_m"] if vals["design_cant_m"] is not None else nan
    c["cant_m"] = cant
    c["sigma_cant_m"] = vals["sigma_cant_m"] if vals["sigma_cant_m"] is not None else nan
    c["design_cant_m"] = design_cant
    c["cant_dev_m"] = cant - design_cant
    c["twist_m"] = backward_difference(cant, config.twist_base_m, step)
    c["twist_rate_m_per_m"] = c["twist_m"] / config.twist_base_m
    # twist less the design twist (the cant ramp of transitions): the twist of the cant deviation
    c["twist_dev_m"] = backward_difference(c["cant_dev_m"], config.twist_base_m, step)

    L = config.versine_chord_m
    c["versine_h_m"] = v_sign * lat_sign * horizontal_versine(E, N, L, step)
    c["design_versine_h_m"] = v_sign * lat_sign * horizontal_versine(dE, dN, L, step) if has_design else nan
    # measured - design versine = versine of the deviation (versine is linear; exact for the
    # vertical, first order in the deviation for the horizontal)
    c["versine_h_dev_m"] = v_sign * versine(c["lateral_dev_m"], L, step)
    c["versine_v_m"] = v_sign * versine(H, L, step)
    c["design_versine_v_m"] = v_sign * versine(dH, L, step)
    c["versine_v_dev_m"] = v_sign * versine(vert, L, step)

    for chord, spacing in config.long_chords_m:
        c[long_chord_name(chord, spacing, "lat")] = long_chord_check(c["lateral_dev_m"], chord, spacing, step)
        c[long_chord_name(chord, spacing, "vert")] = long_chord_check(vert, chord, spacing, step)
    # settled: these values are checked against limits, and near the record's ends the filter's
    # start-up transient alone can exceed them (trolley.bands, SETTLED_WAVELENGTHS)
    for b in config.bands:
        c[f"align_{b}_m"] = band(c["lateral_dev_m"], step, b, settled=True)
    for b in config.bands:
        c[f"level_{b}_m"] = band(vert, step, b, settled=True)

    names = column_names(config)
    assert list(c) == names, (list(c), names)
    return TrackGeometry(chainage_m=grid, step_m=step, columns=c, config=config, resampled=resampled,
                         gaps_m=tuple(gaps))


@dataclass(frozen=True)
class RailValues:
    """Deviations of each rail from its design position (SI, in the sheet's sign conventions).

    Attributes
    ----------
    left_alignment_m, right_alignment_m : lateral deviation of the left / right rail.
    left_level_m, right_level_m : vertical deviation of the left / right rail (+ up).
    """

    left_alignment_m: np.ndarray
    right_alignment_m: np.ndarray
    left_level_m: np.ndarray
    right_level_m: np.ndarray


def rail_values(geometry: TrackGeometry) -> RailValues:
    """Left and right rail alignment and level from the centre line, the gauge and the cant.

    The centre line lies midway between the rails: a gauge wider by ``g`` puts each rail ``g/2``
    further out, and a cant deviation ``c`` (left rail higher by ``c`` than designed) raises the
    left rail by ``c/2`` and lowers the right one by ``c/2``:

        left alignment  = lateral dev - sL g/2      right alignment = lateral dev + sL g/2
        left level      = vertical dev + sC c/2     right level     = vertical dev - sC c/2

    with sL = +1 when lateral values are + to the right, -1 when + to the left, and sC = +1 when
    cant is + with the left rail high, -1 otherwise (``geometry.config``). NaN where the gauge
    (alignment) or the cant deviation (level) is not measured.

    Parameters
    ----------
    geometry : computed geometry (columns lateral_dev_m, vertical_dev_m, gauge_dev_m, cant_dev_m).

    Returns
    -------
    RailValues

    References
    ----------
    EN 13848-1 (alignment and longitudinal level are defined per rail); the centre-line
    deviations of this module; docs/track_geometry.md.
    """
    c = geometry.columns
    sl = _LATERAL_SIGNS[geometry.config.lateral_sign]
    sc = _CANT_SIGNS[geometry.config.cant_sign]
    half_g = 0.5 * c["gauge_dev_m"]
    half_c = 0.5 * c["cant_dev_m"]
    return RailValues(left_alignment_m=c["lateral_dev_m"] - sl * half_g,
                      right_alignment_m=c["lateral_dev_m"] + sl * half_g,
                      left_level_m=c["vertical_dev_m"] + sc * half_c,
                      right_level_m=c["vertical_dev_m"] - sc * half_c)


@dataclass(frozen=True)
class ColumnStats:
    """Statistics of one parameter over the valid stations (SI)."""

    name: str
    count: int
    mean: float
    std: float
    minimum: float
    maximum: float
    rms: float


def column_stats(name: str, x: np.ndarray) -> ColumnStats:
    """Count, mean, std, min, max and RMS of the finite values of ``x``."""
    v = np.asarray(x, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return ColumnStats(name, 0, np.nan, np.nan, np.nan, np.nan, np.nan)
    return ColumnStats(name, int(v.size), float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0,
                       float(v.min()), float(v.max()), float(np.sqrt(np.mean(v * v))))


#: the absolute parameters: a station's position against the design, which only the prism fixes
#: on CPIII give (the relative ones, gauge, cant, twist, versines, chords and bands, come from the
#: trolley's own sensors over a short base)
ABSOLUTE_COLUMNS = ("lateral_dev_m", "vertical_dev_m", "slew_m", "lift_m")
#: a fix farther than this in plan from every station is not on the surveyed track (half the
#: 4.5-5 m spacing of two tracks; the prism stands at most about 0.8 m beside the track point)
FIX_NEAR_TRACK_M = 2.5


def nearest_stations(E_m: np.ndarray, N_m: np.ndarray, point_E_m: np.ndarray, point_N_m: np.ndarray,
                     max_distance_m: float = FIX_NEAR_TRACK_M) -> np.ndarray:
    """Index of the station nearest in plan to each point, -1 where none lies within
    ``max_distance_m`` (or the track has no finite station).

    A k-d tree (scipy.spatial.cKDTree): the distance matrix of every point to every station
    needed 8 bytes x points x stations, 2.5 GB for 2000 fixes on 160 000 stations.
    """
    from scipy.spatial import cKDTree

    E_m, N_m = np.asarray(E_m, dtype=float), np.asarray(N_m, dtype=float)
    pts = np.column_stack([np.asarray(point_E_m, dtype=float), np.asarray(point_N_m, dtype=float)]).reshape(-1, 2)
    out = np.full(pts.shape[0], -1, dtype=np.intp)
    finite = np.flatnonzero(np.isfinite(E_m) & np.isfinite(N_m))
    ok = np.isfinite(pts).all(axis=1)
    if finite.size == 0 or not ok.any():
        return out
    # coordinates relative to one station: grid eastings of 5e5 m would cost the tree digits
    e0, n0 = E_m[finite[0]], N_m[finite[0]]
    tree = cKDTree(np.column_stack([E_m[finite] - e0, N_m[finite] - n0]))
    d, i = tree.query(pts[ok] - [e0, n0], distance_upper_bound=max_distance_m)
    hit = np.isfinite(d)
    idx = np.full(d.shape, -1, dtype=np.intp)
    idx[hit] = finite[i[hit]]
    out[ok] = idx
    return out


def fixed_span(chainage_m: np.ndarray, fix_chainage_m: np.ndarray) -> np.ndarray:
    """Stations between the first and the last fix (bool per station): where the position rests
    on fixes at both sides, and the smoother bridges the dead reckoning between two of them
    (Jiang 2017 Sec. 4.3). Outside this span the absolute position is dead reckoning from one
    fix, whose error and sigma grow with the distance without a second fix to bound them
    (Jiang 2017 Sec. 3.2, Eq. 7-10); all False without a fix.

    Parameters
    ----------
    chainage_m : station chainages, m (sorted).
    fix_chainage_m : chainage of each fix used by the smoother (e.g. from :func:`nearest_stations`).
    """
    s = np.asarray(chainage_m, dtype=float)
    f = np.asarray(fix_chainage_m, dtype=float)
    f = f[np.isfinite(f)]
    if f.size == 0:
        return np.zeros(s.shape, dtype=bool)
    return (s >= f.min()) & (s <= f.max())


__all__ = ["GeometryConfig", "TrackInput", "TrackGeometry", "ColumnStats", "RailValues", "rail_values", "track_geometry",
           "column_names", "column_stats", "long_chord_name", "versine", "horizontal_versine",
           "long_chord_check", "backward_difference", "shifted", "lateral_sigma",
           "heading_from_positions", "uniform_grid", "chainage_gaps", "ABSOLUTE_COLUMNS", "FIX_NEAR_TRACK_M",
           "nearest_stations", "fixed_span"]
