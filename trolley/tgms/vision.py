"""Rail-head profile fit to the laser points of every camera frame (Escalona 2021 Sec. 5).

For each frame and rail the pose (y0, z0, alpha) of the rail-profile frame in the TGMS frame is the
minimiser of the sum of squared distances of the frame's laser points to the theoretical head
profile (Sec. 5, Fig. 6), made robust to reflections by iteratively reweighted least squares: a
Huber stage from the rough start, then a Tukey biweight stage that gives outliers zero weight.
All frames are solved at once: one Gauss-Newton step is a handful of numpy passes over all points
(distance and gradient by bilinear lookup in the profile's signed-distance field, normal
equations accumulated per frame with ``np.bincount``, batched 3x3 solves).

A frame is *flagged* (``ok`` False, values NaN), never guessed, when it has too few inlier points,
its inlier RMS is too large, the lateral position is not determined (no points on the gauge face),
or the iteration did not settle.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trolley.tgms.profiles import RailProfile


@dataclass(frozen=True)
class FitOptions:
    """Settings of the robust profile fit (m, rad).

    Attributes
    ----------
    huber_m : Huber threshold of the first stage.
    tukey_m : Tukey biweight cut-off of the second stage (points beyond get zero weight).
    huber_iterations, tukey_iterations : Gauss-Newton iterations per stage.
    min_points : fewest inlier points for a usable frame.
    max_rms_m : largest inlier RMS distance for a usable frame.
    max_sigma_m : largest 1-sigma of y0 or z0 for a usable frame.
    max_step_m : the last step must be smaller than this.
    """

    huber_m: float = 1.0e-3
    tukey_m: float = 0.6e-3
    huber_iterations: int = 6
    tukey_iterations: int = 4
    min_points: int = 20
    max_rms_m: float = 0.25e-3
    max_sigma_m: float = 0.1e-3
    max_step_m: float = 0.02e-3


@dataclass
class RailFit:
    """Per-frame rail-profile pose in the TGMS frame for one rail (arrays of length n_frames).

    Attributes
    ----------
    y_m, z_m : origin of the rail-profile frame (gauge point laterally, running surface
        vertically), TGMS frame FRD; NaN where flagged.
    angle_rad : roll of the rail-profile frame about x in the TGMS frame (FRD sign); NaN if flagged.
    sigma_y_m, sigma_z_m, sigma_angle_rad : 1-sigma from the fit covariance.
    n_inliers : points with non-zero final weight.
    rms_m : RMS distance of the inliers.
    ok : True where the frame is usable.
    """

    y_m: np.ndarray
    z_m: np.ndarray
    angle_rad: np.ndarray
    sigma_y_m: np.ndarray
    sigma_z_m: np.ndarray
    sigma_angle_rad: np.ndarray
    n_inliers: np.ndarray
    rms_m: np.ndarray
    ok: np.ndarray


def _initial_pose(frame: np.ndarray, y: np.ndarray, z: np.ndarray, n_frames: int):
    """Rough pose per frame: running surface from a low quantile of z, gauge point from the
    innermost points 10-18 mm below it (right-rail coordinates: gauge face on the -y side)."""
    order = np.lexsort((z, frame))
    fs, zs = frame[order], z[order]
    counts = np.bincount(frame, minlength=n_frames)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    k = np.minimum(np.maximum(counts // 20, 2), np.maximum(counts - 1, 0))
    z0 = np.full(n_frames, np.nan)
    has = counts > 0
    z0[has] = zs[starts[has] + k[has]]
    dz = z - z0[frame]
    band = (dz > 0.010) & (dz < 0.018)
    ymin = np.full(n_frames, np.inf)
    np.minimum.at(ymin, frame[band], y[band])
    # fall back to the median lateral position minus half a head where no gauge-face point exists
    ymed = np.full(n_frames, np.nan)
    if has.any():
        oy = np.lexsort((y, frame))
        ymed[has] = y[oy][starts[has] + counts[has] // 2]
    y0 = np.where(np.isfinite(ymin), ymin, ymed - 0.036)
    return y0, z0


def fit_rail(profile: RailProfile, frame: np.ndarray, y_m: np.ndarray, z_m: np.ndarray,
             n_frames: int, side: str = "right", options: FitOptions = FitOptions()) -> RailFit:
    """Robust fit of the rail-head profile to every frame's laser points, all frames at once.

    Parameters
    ----------
    profile : the rail-head model (right-rail coordinates; mirrored for ``side="left"``).
    frame : (n,) frame index (0 .. n_frames-1) of each point.
    y_m, z_m : (n,) point coordinates in the TGMS frame (the laser-plane points of Eq. 19).
    n_frames : number of frames (frames without points are flagged).
    side : "left" or "right".
    options : FitOptions.

    Returns
    -------
    RailFit with the pose of the rail-profile frame in the TGMS frame per frame.

    References
    ----------
    Escalona 2021 Sec. 5 (fit of the theoretical profile to the cloud of points).
    """
    frame = np.asarray(frame, dtype=np.intp)
    mirror = -1.0 if side == "left" else 1.0
    y = mirror * np.asarray(y_m, float)
    z = np.asarray(z_m, float)
    oy, oz = _initial_pose(frame, y, z, n_frames)
    good0 = np.isfinite(oy) & np.isfinite(oz)
    oy = np.where(good0, oy, 0.0)
    oz = np.where(good0, oz, 0.0)
    al = np.zeros(n_frames)
    n_it = options.huber_iterations + options.tukey_iterations
    step = np.full(n_frames, np.inf)
    w = np.ones_like(y)
    eps = 1e-16
    for it in range(n_it):
        c, s = np.cos(al)[frame], np.sin(al)[frame]
        dy, dz = y - oy[frame], z - oz[frame]
        qy = c * dy + s * dz            # q = R(-alpha) (p - o)
        qz = -s * dy + c * dz
        d, gy, gz, inside = profile.signed_distance(qy, qz)
        # Jacobian rows: d/d(oy, oz) = -(R(alpha) g)^T ; d/dalpha = gy qz - gz qy
        j0 = -(c * gy - s * gz)
        j1 = -(s * gy + c * gz)
        j2 = gy * qz - gz * qy
        a = np.abs(d)
        if it < options.huber_iterations:
            k = options.huber_m
            w = np.where(a <= k, 1.0, k / np.maximum(a, eps))
        else:
            k = options.tukey_m
            w = np.where(a < k, (1 - (a / k) ** 2) ** 2, 0.0)
        w = w * inside
        def acc(v):
            return np.bincount(frame, weights=w * v, minlength=n_frames)
        A = np.empty((n_frames, 3, 3))
        A[:, 0, 0] = acc(j0 * j0); A[:, 1, 1] = acc(j1 * j1); A[:, 2, 2] = acc(j2 * j2)
        A[:, 0, 1] = A[:, 1, 0] = acc(j0 * j1)
        A[:, 0, 2] = A[:, 2, 0] = acc(j0 * j2)
        A[:, 1, 2] = A[:, 2, 1] = acc(j1 * j2)
        b = -np.column_stack([acc(j0 * d), acc(j1 * d), acc(j2 * d)])
        # small Levenberg damping keeps frames with degenerate clouds finite (they get flagged)
        tr = np.trace(A, axis1=1, axis2=2)
        A = A + (1e-9 * tr + 1e-12)[:, None, None] * np.eye(3)
        dx = np.linalg.solve(A, b[:, :, None])[:, :, 0]
        # keep each step modest: the start can be a few mm off
        scale = np.minimum(1.0, 0.004 / np.maximum(np.abs(dx[:, :2]).max(axis=1), eps))
        dx *= scale[:, None]
        dx[:, 2] = np.clip(dx[:, 2], -0.05, 0.05)
        oy += dx[:, 0]; oz += dx[:, 1]; al += dx[:, 2]
        step = np.abs(dx[:, :2]).max(axis=1)
    # final residuals, weights and covariance at the solution
    c, s = np.cos(al)[frame], np.sin(al)[frame]
    dy, dz = y - oy[frame], z - oz[frame]
    qy, qz = c * dy + s * dz, -s * dy + c * dz
    d, gy, gz, inside = profile.signed_distance(qy, qz)
    k = options.tukey_m
    inl = (np.abs(d) < k) & inside
    w = np.where(inl, (1 - (d / k) ** 2) ** 2, 0.0)
    j0, j1, j2 = -(c * gy - s * gz), -(s * gy + c * gz), gy * qz - gz * qy
    def acc(v):
        return np.bincount(frame, weights=v, minlength=n_frames)
    n_in = np.bincount(frame, weights=inl.astype(float), minlength=n_frames).astype(int)
    rms = np.sqrt(acc(inl * d * d) / np.maximum(n_in, 1))
    A = np.empty((n_frames, 3, 3))
    A[:, 0, 0] = acc(w * j0 * j0); A[:, 1, 1] = acc(w * j1 * j1); A[:, 2, 2] = acc(w * j2 * j2)
    A[:, 0, 1] = A[:, 1, 0] = acc(w * j0 * j1)
    A[:, 0, 2] = A[:, 2, 0] = acc(w * j0 * j2)
    A[:, 1, 2] = A[:, 2, 1] = acc(w * j1 * j2)
    sig2 = acc(w * d * d) / np.maximum(n_in - 3, 1)
    det = np.linalg.det(A)
    cov = np.full_like(A, np.inf)
    inv_ok = np.abs(det) > 1e-300
    cov[inv_ok] = np.linalg.inv(A[inv_ok]) * sig2[inv_ok, None, None]
    sy, sz, sa = (np.sqrt(np.abs(cov[:, i, i])) for i in range(3))
    ok = (good0 & (n_in >= options.min_points) & (rms <= options.max_rms_m)
          & (sy <= options.max_sigma_m) & (sz <= options.max_sigma_m)
          & (step <= options.max_step_m) & np.isfinite(oy))
    nan = np.where(ok, 1.0, np.nan)
    return RailFit(y_m=mirror * oy * nan, z_m=oz * nan, angle_rad=mirror * al * nan,
                   sigma_y_m=sy * nan, sigma_z_m=sz * nan, sigma_angle_rad=sa * nan,
                   n_inliers=n_in, rms_m=rms, ok=ok)
