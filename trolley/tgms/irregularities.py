"""Track irregularities from the vision, the relative attitude and the relative trajectory
(Escalona 2021 Sec. 6), and their resampling on a uniform station grid.

With the rail-profile origins O_l, O_r measured in the TGMS frame (``vision``), the relative roll
phi and the relative position r = [0, r_y, r_z] of the TGMS (all FRD), rotating the vision
vectors into the track frame with the small-angle matrix of Eq. 23 gives

    gauge variation   = (dy - phi dz) - 2 L_r                      (Eq. 24)
    cross level       = phi dy + dz                                (Eq. 24)
    alignment         = (Y - phi Z) + r_y                          (Eq. 27)
    vertical profile  = -((Z + phi Y) + r_z)                       (Eq. 27)

with dy = y_r - y_l, dz = z_r - z_l, Y = (y_l + y_r) / 2, Z = (z_l + z_r) / 2. In FRD these are
directly the published signs: gauge > 0 wider, cross level > 0 left rail higher (its z is
smaller), alignment > 0 displaced right; the vertical profile changes sign because z is down.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Irregularities:
    """Irregularities (m) with 1-sigma (m) at a set of stations; NaN where not measured."""

    s_m: np.ndarray
    gauge_variation_m: np.ndarray
    cross_level_m: np.ndarray
    alignment_m: np.ndarray
    vertical_profile_m: np.ndarray
    sigma_gauge_variation_m: np.ndarray
    sigma_cross_level_m: np.ndarray
    sigma_alignment_m: np.ndarray
    sigma_vertical_profile_m: np.ndarray

    NAMES = ("gauge_variation", "cross_level", "alignment", "vertical_profile")


def irregularities(s_m, y_l, z_l, y_r, z_r, roll, r_y, r_z, half_rail_spacing_m: float,
                   sig_yl=0.0, sig_zl=0.0, sig_yr=0.0, sig_zr=0.0, sig_roll=0.0, sig_ry=0.0,
                   sig_rz=0.0) -> Irregularities:
    """Escalona 2021 Eq. 24 and 27 (FRD form, see the module docstring) at every frame.

    Parameters
    ----------
    s_m : stations of the frames.
    y_l, z_l, y_r, z_r : rail-profile origins of the left and right rail in the TGMS frame, m.
    roll : relative roll of the TGMS (FRD), rad.
    r_y, r_z : TGMS position relative to the design TF (FRD, r_z < 0 above the rails), m.
    half_rail_spacing_m : L_r.
    sig_* : 1-sigma of the inputs (uncorrelated), for the first-order output sigmas; a NaN
        sig_roll (no covariance) leaves the gauge sigma from the vision alone, the others NaN.

    Returns
    -------
    Irregularities
    """
    dy, dz = y_r - y_l, z_r - z_l
    Y, Z = 0.5 * (y_l + y_r), 0.5 * (z_l + z_r)
    gv = dy - roll * dz - 2 * half_rail_spacing_m
    cl = roll * dy + dz
    al = Y - roll * Z + r_y
    vp = -(Z + roll * Y + r_z)
    # without a roll covariance (gradient-descent attitude: NaN) the gauge sigma keeps its vision
    # part: its roll term dz sigma_roll is second order (dz ~ mm); the three others depend on the
    # roll to first order (lever arms dy, Z, Y) and stay NaN rather than understated
    s_gv = np.sqrt(sig_yl ** 2 + sig_yr ** 2 + (dz * np.nan_to_num(sig_roll, nan=0.0)) ** 2)
    s_cl = np.sqrt(sig_zl ** 2 + sig_zr ** 2 + (dy * sig_roll) ** 2)
    s_al = np.sqrt(0.25 * (sig_yl ** 2 + sig_yr ** 2) + (Z * sig_roll) ** 2 + sig_ry ** 2)
    s_vp = np.sqrt(0.25 * (sig_zl ** 2 + sig_zr ** 2) + (Y * sig_roll) ** 2 + sig_rz ** 2)
    return Irregularities(s_m, gv, cl, al, vp, s_gv, s_cl, s_al, s_vp)


def rails_in_laser_track_frame(alignment, s_imu, s_laser, roll, pitch, yaw, r_y, r_z, u_left, u_right):
    """Rail-profile origins seen by the vision, expressed in the track frame at the laser's station.

    The exact form of Eq. 20-22 for laser planes that are not through the IMU: a point u of the
    TGMS frame is at R^t(s) + A^t(s) (r + A^{t,tgms} u) in the world (Eq. 12), and in the track
    frame of the station s_L it cuts, A^t(s_L)^T (that - R^t(s_L)). With s_L = s and small angles
    this reduces to the matrix of Eq. 23 used in :func:`irregularities`.

    Parameters
    ----------
    alignment : design geometry.
    s_imu, s_laser : (n,) stations of the IMU and of the laser cut.
    roll, pitch, yaw : (n,) TGMS attitude relative to the TF at s_imu (FRD, ZYX).
    r_y, r_z : (n,) TGMS position in the TF at s_imu.
    u_left, u_right : (n, 3) rail-profile origins in the TGMS frame (x: the laser plane's).

    Returns
    -------
    (q_left, q_right) : (n, 3) each, in the TF at s_laser (FRD).
    """
    from scipy.spatial.transform import Rotation

    from trolley.tgms.track import ned_position, track_rotation
    g0 = alignment.evaluate(s_imu)
    g1 = alignment.evaluate(s_laser)
    R0 = track_rotation(g0.heading_rad, g0.slope_rad, g0.cant_rad)
    R1 = track_rotation(g1.heading_rad, g1.slope_rad, g1.cant_rad)
    O0, O1 = ned_position(g0), ned_position(g1)
    Arel = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))
    r = np.column_stack([np.zeros_like(r_y), r_y, r_z])
    out = []
    for u in (u_left, u_right):
        world = O0 + R0.apply(r + Arel.apply(u))
        out.append(R1.inv().apply(world - O1))
    return out[0], out[1]


def resample(s_m: np.ndarray, values: np.ndarray, grid_m: np.ndarray, max_gap_m: float) -> np.ndarray:
    """Linear interpolation of frame values (NaN = flagged) onto a station grid; a grid point is
    NaN unless both neighbouring valid frames lie within ``max_gap_m`` of each other (never
    guessed across a gap of flagged frames)."""
    ok = np.isfinite(values) & np.isfinite(s_m)
    out = np.full(grid_m.shape, np.nan)
    if ok.sum() < 2:
        return out
    s, v = s_m[ok], values[ok]
    order = np.argsort(s, kind="stable")
    s, v = s[order], v[order]
    keep = np.concatenate([[True], np.diff(s) > 0])
    s, v = s[keep], v[keep]
    j = np.searchsorted(s, grid_m)
    exact = s[np.clip(j, 0, len(s) - 1)] == grid_m
    inside = (j > 0) & (j < len(s))
    jj = np.clip(j, 1, len(s) - 1)
    gap = s[jj] - s[jj - 1]
    good = exact | (inside & (gap <= max_gap_m))
    out[good] = np.interp(grid_m[good], s, v)
    return out


#: shortest distance between two usable frames across which the grid is left empty, m (or two steps
#: when that is longer)
MIN_EMPTY_GAP_M = 0.5


def empty_gap_m(step_m: float) -> float:
    """Distance between neighbouring usable frames beyond which :func:`resample_irregularities`
    leaves the grid points between them empty, m."""
    return max(2.0 * step_m, MIN_EMPTY_GAP_M)


def resample_irregularities(irr: Irregularities, step_m: float, max_gap_m: float | None = None) -> Irregularities:
    """The irregularities on the uniform grid k * step within the frames' stations (frames with a
    station and NaN values, e.g. flagged ones, extend the grid with empty points)."""
    ok = np.isfinite(irr.s_m)
    lo = np.ceil(np.nanmin(irr.s_m[ok]) / step_m) * step_m
    hi = np.nanmax(irr.s_m[ok])
    grid = np.round(np.arange(lo, hi + 1e-9, step_m) / step_m) * step_m
    gap = empty_gap_m(step_m) if max_gap_m is None else max_gap_m
    vals = {}
    for name in Irregularities.NAMES:
        vals[f"{name}_m"] = resample(irr.s_m, getattr(irr, f"{name}_m"), grid, gap)
        vals[f"sigma_{name}_m"] = resample(irr.s_m, getattr(irr, f"sigma_{name}_m"), grid, gap)
    return Irregularities(s_m=grid, **vals)
