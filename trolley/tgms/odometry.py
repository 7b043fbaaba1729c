"""Odometry of the TGMS along the track (Escalona 2021 Sec. 8).

1. Encoder counts to an approximate station s_app (rolling without slipping), then a smooth
   s_app(t), V(t) and V'(t) on a uniform time grid (Savitzky-Golay fit).
2. Correction by curvature matching: the measured horizontal curvature rho_exp = omega_z / V
   (Eq. 40) is compared with the design curvature over windows (``match_curves``): one per curve
   of the length of the curvature function, anchored at the curve exit (Eq. 41 as printed,
   default), or one per curve entry and exit (each clothoid or curvature jump with some flat
   curvature either side, Fig. 10's points 1-4), anchored at the middle of the ramp; the
   normalised squared error ne2 = e2 / I2 (Eq. 41-43) is minimal at the shift where the measured
   curvature sits on the design; the minimum (refined by a parabola) gives the measured station
   of the anchor; with the known start station these anchors re-map the stations in between
   linearly (Fig. 11). ``passes`` > 1 repeats the matching on the re-mapped stations.
3. Heading matching (``heading_fit``, the integral form of Eq. 40-41): the gyro z angle
   int omega_z dt is fitted to the design track frame's z angle psi_d(s) over the whole ride, with
   the encoder scale error k (s = s0 + (1 + k)(s_app - s0): a wheel diameter off its nominal
   value), a constant gyro offset (bias plus Earth rate) and the unknown initial angle as the
   only parameters. Why: the curvature the vehicle follows besides the design is that of the
   alignment irregularities, whose spectrum rises as Omega^2 in curvature (their slope is about
   white between 300 m and 8 m wavelengths, Claus & Schiehlen's low-disturbance spectrum), so the
   minimum-variance comparison is in the angle, where that noise is white, and over every curve,
   ramp and straight of the ride at once.
4. ``method="fused"`` (default): the heading fit's scale and the scale implied by each Eq. 41
   anchor are combined by their inverse variances (each sigma from its own residuals, inflated by
   the residuals' correlation time); the stations are then s0 + (1 + k)(s_app - s0), one scale
   for the ride (the wheel's rolling diameter; a ride long enough for the gyro offset or the
   wheel to drift would need the model piecewise). On 40 simulated 300 m rides (seeds 1-20, 5 and
   15 m/s) the rms station error over the three cant ramps was 0.162 m for the raw encoder,
   0.135 m with the Eq. 41 anchors and the linear re-mapping, 0.058 m with the heading fit and
   0.056 m fused (the anchors' sigmas, ~0.8e-3 in scale against ~0.25e-3, give them little
   weight; their errors and the heading fit's were uncorrelated, r = -0.1); the normalised
   errors had an rms of 1.1 (anchors) and 1.26 (heading fit), so the sigmas are about right.
   The figures above are of a constant-scale simulated encoder (the model here). The simulator's
   default encoder has errors outside this model too (``simulate.ENCODER_DRIFT``: creep 1e-4
   s^2/m times the acceleration and a 1e-4 rms, 100 m correlated rolling-radius variation): on
   seeds 1-3 at 5 and 15 m/s their part of the station error was 3-9 mm rms, k moved by
   <= 0.05e-3 (sigma ~0.25e-3) and the worst cross-level std was 0.091 mm (0.092 without); at
   five times those amplitudes, 0.088 mm. A solid wheelset that shifts outward in a curve rolls
   on radii r0 +- gamma y whose mean is r0: to first order the axle's rotation still counts the
   centre-line distance, so a curvature-following scale error is not simulated.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.signal import savgol_filter

from trolley.alignment import Alignment, Clothoid, Line
from trolley.tgms.track import angular_velocity_body, track_rotation


@dataclass
class Odometry:
    """Station and speed on the processing time grid.

    Attributes
    ----------
    t_s : uniform time grid.
    s_app_m : encoder station (before curvature matching).
    s_m : corrected station.
    v_m_s, a_m_s2 : forward speed and its time derivative.
    anchors_app_m, anchors_design_m : matched points (encoder station -> design station).
    ne2_min : the normalised squared error at each accepted match (Eq. 43).
    anchors_sigma_m : 1-sigma of each anchor's station (from the curvature residuals).
    scale_error, sigma_scale_error : encoder scale error k (s = s0 + (1 + k)(s_app - s0)) used by
        the "heading" and "fused" methods and its 1-sigma (NaN for "anchors").
    heading : the heading fit (None unless it was run).
    """

    t_s: np.ndarray
    s_app_m: np.ndarray
    s_m: np.ndarray
    v_m_s: np.ndarray
    a_m_s2: np.ndarray
    anchors_app_m: np.ndarray
    anchors_design_m: np.ndarray
    ne2_min: np.ndarray
    anchors_sigma_m: np.ndarray | None = None
    scale_error: float = float("nan")
    sigma_scale_error: float = float("nan")
    heading: "HeadingFit | None" = None


@dataclass
class HeadingFit:
    """Result of ``heading_fit``.

    Attributes
    ----------
    scale_error : k, with s = s0 + (1 + k)(s_app - s0).
    sigma_scale_error : its 1-sigma (least squares, residual variance inflated by the residuals'
        correlation time).
    gyro_offset_rad_s : constant z-rate offset fitted (gyro bias plus Earth rate).
    residual_rms_rad : rms of the angle residuals.
    correlation_samples : the residuals' correlation time in samples (the inflation factor).
    """

    scale_error: float
    sigma_scale_error: float
    gyro_offset_rad_s: float
    residual_rms_rad: float
    correlation_samples: float


def correlation_samples(r: np.ndarray) -> float:
    """Integral correlation time of a residual series, in samples: 1 + 2 sum of its
    autocorrelation up to the first negative lag (at least 1).

    The factor by which correlated residuals inflate a least-squares variance computed as if they
    were white (the effective number of samples is n / this).
    """
    r = np.asarray(r, float) - np.mean(r)
    n = len(r)
    if n < 4 or not np.any(r):
        return 1.0
    f = np.fft.rfft(r, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:n]
    ac = ac / ac[0]
    neg = np.nonzero(ac <= 0)[0]
    last = int(neg[0]) if len(neg) else n
    return float(max(1.0, 1.0 + 2.0 * np.sum(ac[1:last])))


def design_z_angle(alignment: Alignment, s_lo: float, s_hi: float, ds: float = 0.05):
    """Design track frame's z angle along the track: the integral over s of its angular velocity
    about its own z axis (FRD) per metre, which is what int omega_z dt measures on a TGMS riding
    the design (rho_h cos(cant) cos(slope) - slope' sin(cant), Escalona Eq. 5, exact here by
    differentiating the design attitude).

    Parameters
    ----------
    alignment : design.
    s_lo, s_hi : station range (clipped to the alignment).
    ds : grid step, m.

    Returns
    -------
    (s_grid, psi_rad, omega_per_m) : grid, angle (0 at s_grid[0]) and its derivative (1/m).
    """
    lo = max(s_lo, alignment.start_chainage_m)
    hi = min(s_hi, alignment.end_chainage_m)
    s = np.arange(lo, hi + ds, ds)
    s = s[s <= alignment.end_chainage_m]
    g = alignment.evaluate(s)
    w = angular_velocity_body(track_rotation(g.heading_rad, g.slope_rad, g.cant_rad), ds)[:, 2]
    return s, cumulative_trapezoid(w, s, initial=0.0), w


def heading_fit(t: np.ndarray, omega_z: np.ndarray, s_app: np.ndarray, alignment: Alignment,
                s0_m: float, iterations: int = 4) -> HeadingFit:
    """Encoder scale error from the gyro z angle matched to the design z angle over the whole ride
    (the integral form of Escalona 2021 Eq. 40-41, see the module docstring).

    Model, least squares over every sample (Gauss-Newton in k)::

        int_0^t omega_z dt = c + b (t - t_mean) + psi_d(s0 + (1 + k)(s_app - s0)) + noise

    c is the unknown initial angle, b a constant rate offset (gyro bias and Earth rate: a drift
    that would otherwise read as a stretch), k the encoder scale error. The standstill at the
    start (s = s0) and the straights, where psi_d is flat, fix c and b; the curves fix k.

    Parameters
    ----------
    t : uniform times, s.
    omega_z : gyro z rate on ``t`` (rad/s).
    s_app : encoder stations on ``t``.
    alignment : design.
    s0_m : known station at encoder count 0.
    iterations : Gauss-Newton iterations (k is tiny: 2 suffice).

    Returns
    -------
    HeadingFit (scale error 0 with an infinite sigma on a ride without curvature)

    References
    ----------
    Escalona 2021 Eq. 40-41 (curvature matching, here integrated once); the track spectrum that
    makes the angle the white-noise domain: Claus & Schiehlen (German low-disturbance PSD, see
    ``trolley.tgms.simulate``).
    """
    psi_m = cumulative_trapezoid(omega_z, t, initial=0.0)
    lever = s_app - s0_m
    # the design must cover every station the scale can map to
    span = 0.01 * (np.max(np.abs(lever)) + 1.0)
    sg, psi_d, w_d = design_z_angle(alignment, float(np.min(s_app)) - span, float(np.max(s_app)) + span)
    tc = t - t.mean()
    k = 0.0
    for it in range(iterations + 1):  # the last pass only evaluates the fit at the final k
        s = s0_m + (1.0 + k) * lever
        y = psi_m - np.interp(s, sg, psi_d)
        A = np.column_stack([np.ones_like(t), tc, np.interp(s, sg, w_d) * lever])
        p, *_ = np.linalg.lstsq(A, y, rcond=None)
        if it < iterations:
            k += p[2]
    r = y - A @ p
    tau = correlation_samples(r)
    N = A.T @ A
    if not np.linalg.cond(N) < 1e14:
        # no curvature on the ride (a straight): the angle says nothing about the scale
        return HeadingFit(scale_error=0.0, sigma_scale_error=float("inf"), gyro_offset_rad_s=float(p[1]),
                          residual_rms_rad=float(np.std(r)), correlation_samples=tau)
    cov = np.linalg.inv(N) * np.var(r) * tau
    return HeadingFit(scale_error=float(k + p[2]), sigma_scale_error=float(np.sqrt(cov[2, 2])),
                      gyro_offset_rad_s=float(p[1]), residual_rms_rad=float(np.std(r)),
                      correlation_samples=tau)


def fused_scale_error(heading: HeadingFit | None, anchors_app: np.ndarray, anchors_des: np.ndarray,
                      anchors_sigma: np.ndarray, s0_m: float, min_lever_m: float = 10.0):
    """Inverse-variance combination of the heading fit's scale error and those implied by the
    Eq. 41 anchors.

    Anchor i (encoder station a_i matched to design station d_i) implies
    k_i = (d_i - s0) / (a_i - s0) - 1 with sigma_i / (a_i - s0); anchors closer than
    ``min_lever_m`` to the start carry no scale information and are skipped.

    Returns
    -------
    (k, sigma_k) : (0, inf) when there is nothing to combine.
    """
    ks, ws = [], []
    if heading is not None and np.isfinite(heading.sigma_scale_error) and heading.sigma_scale_error > 0:
        ks.append(heading.scale_error)
        ws.append(heading.sigma_scale_error ** -2)
    lever = np.asarray(anchors_app, float) - s0_m
    ok = (lever > min_lever_m) & np.isfinite(anchors_sigma) & (np.asarray(anchors_sigma) > 0)
    if ok.any():
        ks.extend((np.asarray(anchors_des)[ok] - s0_m) / lever[ok] - 1.0)
        ws.extend((np.asarray(anchors_sigma)[ok] / lever[ok]) ** -2)
    if not ws:
        return 0.0, float("inf")
    w = np.asarray(ws)
    return float(np.sum(w * np.asarray(ks)) / np.sum(w)), float(1.0 / np.sqrt(np.sum(w)))


def encoder_motion(t_grid: np.ndarray, t_enc: np.ndarray, counts: np.ndarray, metres_per_count: float,
                   s0_m: float, window_s: float = 0.25):
    """Encoder station, speed and acceleration on a uniform time grid.

    Parameters
    ----------
    t_grid : uniform times, s.
    t_enc, counts : encoder samples.
    metres_per_count : distance of one count (pi D / pulses per revolution).
    s0_m : station at count 0.
    window_s : Savitzky-Golay window (quadratic), s.

    Returns
    -------
    s_m, v_m_s, a_m_s2 on ``t_grid``.
    """
    dt = float(t_grid[1] - t_grid[0])
    # counts are floor(distance / step): the mid-step is the unbiased distance estimate
    s = s0_m + np.interp(t_grid, t_enc, (counts + 0.5) * metres_per_count)
    win = _smoothing_window(dt, window_s)
    s_s = savgol_filter(s, win, 2, mode="interp")
    v = savgol_filter(s, win, 2, deriv=1, delta=dt, mode="interp")
    a = savgol_filter(s, 2 * win + 1, 2, deriv=2, delta=dt, mode="interp")
    return s_s, np.maximum(v, 0.0), a


def _smoothing_window(dt: float, window_s: float) -> int:
    return max(5, int(round(window_s / dt)) | 1)


def min_grid_samples(dt: float, window_s: float = 0.25) -> int:
    """Fewest processing-grid samples :func:`encoder_motion` can smooth: its acceleration's
    Savitzky-Golay window, 2 w + 1 samples."""
    return 2 * _smoothing_window(dt, window_s) + 1


def curve_windows(alignment: Alignment) -> list[tuple[float, float]]:
    """(entry, exit) stations of every curvature function (runs of non-straight elements)."""
    hz = alignment.horizontal
    out = []
    start = None
    for i, el in enumerate(hz.elements):
        if not isinstance(el, Line):
            if start is None:
                start = hz.element_chainage_m[i]
        elif start is not None:
            out.append((float(start), float(hz.element_chainage_m[i])))
            start = None
    if start is not None:
        out.append((float(start), float(hz.element_chainage_m[-1])))
    return out


def curvature_changes(alignment: Alignment) -> list[tuple[float, float]]:
    """(start, end) stations of every change of the design curvature: each clothoid, and each
    junction where the curvature jumps (start = end). These are the curve entries and exits of
    Escalona 2021 Fig. 10 (and the inner changes of a double trapezoid)."""
    hz = alignment.horizontal
    ch = np.asarray(hz.element_chainage_m, dtype=float)
    out = []
    for i, el in enumerate(hz.elements):
        if isinstance(el, Clothoid):
            out.append((float(ch[i]), float(ch[i + 1])))
        elif i > 0 and not isinstance(hz.elements[i - 1], Clothoid):
            if abs(el.curvature_start_1_m - hz.elements[i - 1].curvature_end_1_m) > 1e-9:
                out.append((float(ch[i]), float(ch[i])))
    return out


def match_curves(s_app: np.ndarray, rho_exp: np.ndarray, alignment: Alignment, ds: float = 0.05,
                 search_m: float = 6.0, max_ne2: float = 0.3, smooth_m: float = 8.0,
                 windows: str = "curve", margin_m: float | None = None, with_sigma: bool = False):
    """Curvature matching of Escalona 2021 Eq. 41-43.

    The design curvature over a window is slid along the measured curvature (integer grid
    shifts, so no rounding bias); the shift minimising the normalised squared error
    ne2 = e2 / I2 (Eq. 41-43) is refined by a parabola and gives the measured station of the
    window's anchor. "curve" anchors at the exit as Eq. 41 does, which is biased by up to the
    window's stretch (the encoder's scale error times the curve length; ``correct_stations``'s
    ``passes`` > 1 removes it on clean curvature, but on simulated rides the second pass made the
    accuracy worse: the noise dominates). "entry_exit" anchors at the middle of each ramp, where
    the shift information is, so the window's stretch is symmetric about the anchor.

    Parameters
    ----------
    s_app : encoder stations of the rho_exp samples (increasing where moving).
    rho_exp : measured curvature omega_z / V (NaN where the speed is too low).
    alignment : design.
    ds : station step of the matching grid, m.
    search_m : the anchor is searched within +- this of its design station.
    max_ne2 : matches with a larger normalised squared error are rejected.
    smooth_m : sigma of a Gaussian smoothing (in station) applied to both the measured and the
        design curvature before Eq. 41: the vehicle follows the short-wave alignment
        irregularities, whose curvature is as large as the design's, but not its shape. The same
        zero-phase filter on both sides, so it adds no lag between them.
    windows : "curve": one window per curvature function (Eq. 41's Delta s = the curve's length),
        anchored at the curve's exit; "entry_exit": one window per curve entry and exit (each
        clothoid or curvature jump plus ``margin_m`` of flat curvature either side, Escalona
        Fig. 10's points 1-4), anchored at the middle of the ramp.
    margin_m : flat design curvature added either side of each window (default 0 for "curve",
        10 m for "entry_exit").
    with_sigma : also return each anchor's 1-sigma: the least-squares variance of a shift,
        var(residual) * tau / sum(T'^2), with T the smoothed design over the window and tau the
        residuals' correlation time in samples (``correlation_samples``).

    Returns
    -------
    (app, design, ne2) arrays, one per matched window in station order: encoder station ->
    design station of the anchor; with ``with_sigma`` a fourth array, the anchors' 1-sigma (m).

    Notes
    -----
    Measured on 8 simulated 300 m rides (seeds 1-4, 5 and 15 m/s), the anchors' rms error was
    0.095 m for "curve" (8 exits) and 0.26 m for "entry_exit" (20 entries and exits). The
    entry/exit windows are not biased by a lag (the smoothing is the same zero-phase filter on
    both sides) but noisier: a ramp window sees the shift only through the ramp's slope
    (5e-5 1/m^2 on an R 500 / 40 m clothoid), and the long-wave alignment irregularities the
    vehicle follows put 1-3e-5 1/m of curvature into any 8 m-smoothed window; a whole curve
    averages that over two ramps and the arc. A constant gyro offset b (bias plus Earth rate)
    shifts an entry and an exit by -+ b / (V rho_h'), opposite ways, which a whole-curve window
    cancels. Without the irregularities and the vehicle's motion (simulator scales 0) the
    entry/exit anchors were within 0.04 m.
    """
    if windows not in ("curve", "entry_exit"):
        raise ValueError(f"windows must be 'curve' or 'entry_exit', got {windows!r}")
    if margin_m is None:
        margin_m = 0.0 if windows == "curve" else 10.0
    from scipy.ndimage import gaussian_filter1d
    ok = np.isfinite(rho_exp)
    if ok.sum() < 10:
        return (np.array([]),) * (4 if with_sigma else 3)
    grid = np.arange(s_app[ok].min(), s_app[ok].max(), ds)
    # average rho_exp into grid cells centred on the grid points (robust to the uneven sampling
    # in s; cells starting at the grid points would put the measured curve half a cell early)
    idx = np.clip(np.round((s_app[ok] - grid[0]) / ds).astype(int), 0, len(grid) - 1)
    num = np.bincount(idx, rho_exp[ok], len(grid))
    den = np.bincount(idx, None, len(grid))
    have = den > 0
    rho = np.interp(grid, grid[have], num[have] / den[have])
    sig = smooth_m / ds
    rho = gaussian_filter1d(rho, sig, mode="nearest")
    pad = 4 * smooth_m
    app, des, nes, sigs = [], [], [], []
    features = curvature_changes(alignment) if windows == "entry_exit" else curve_windows(alignment)
    for c0, c1 in features:
        w0, w1 = c0 - margin_m, c1 + margin_m
        if w0 - search_m < grid[0] or w1 + search_m > grid[-1]:
            continue
        # integer sample counts: a float comparison with w0 can drop the first sample (a one-step bias)
        n_pad, M = int(round(pad / ds)), int(round((w1 - w0) / ds))
        ext = w0 + ds * np.arange(-n_pad, M + n_pad)
        g = alignment.evaluate(ext)
        T = gaussian_filter1d(g.rho_h_1_m * np.cos(g.cant_rad), sig, mode="nearest")[n_pad:n_pad + M]
        I2 = np.sum(T * T) * ds                                  # Eq. 42
        if I2 <= 0:
            continue
        # shifts that put the window start exactly on grid points (rounding would bias by < ds/2)
        j_start = np.arange(int(np.ceil((w0 - search_m - grid[0]) / ds)), int(np.floor((w0 + search_m - grid[0]) / ds)) + 1)
        shifts = grid[0] + j_start * ds - w0
        j0 = j_start[:, None] + np.arange(M)[None, :]
        d = rho[j0] - T[None, :]
        e2 = np.sum(d * d, axis=1) * ds                          # Eq. 41
        ne2 = e2 / I2                                            # Eq. 43
        k = int(np.argmin(ne2))
        if ne2[k] > max_ne2 or k == 0 or k == len(ne2) - 1:
            continue
        y0, y1, y2 = ne2[k - 1], ne2[k], ne2[k + 1]
        den2 = y0 - 2 * y1 + y2
        off = 0.5 * (y0 - y2) / den2 if den2 > 0 else 0.0
        anchor = c1 if windows == "curve" else 0.5 * (c0 + c1)
        app.append(anchor + shifts[k] + off * ds)
        des.append(anchor)
        nes.append(ne2[k])
        if with_sigma:
            # a shift h changes the model by -h T': Gauss-Markov variance with correlated residuals
            Tp = np.gradient(T, ds)
            sigs.append(float(np.sqrt(np.var(d[k]) * correlation_samples(d[k]) / max(np.sum(Tp * Tp), 1e-300))))
    if with_sigma:
        return np.array(app), np.array(des), np.array(nes), np.array(sigs)
    return np.array(app), np.array(des), np.array(nes)


def remap(s_app: np.ndarray, anchors_app: np.ndarray, anchors_des: np.ndarray):
    """Piecewise-linear re-mapping of encoder stations through the anchors (Fig. 11); beyond the
    last anchor the mean scale of all anchors continues, before the first the station is shifted.

    Returns
    -------
    (s, ds/ds_app) : the corrected stations and the local scale.
    """
    if len(anchors_app) == 0:
        return s_app.copy(), np.ones_like(s_app)
    order = np.argsort(anchors_app)
    a, d = anchors_app[order], anchors_des[order]
    out = np.interp(s_app, a, d)
    slopes = np.diff(d) / np.diff(a) if len(a) >= 2 else np.array([1.0])
    k_end = (d[-1] - d[0]) / (a[-1] - a[0]) if len(a) >= 2 else 1.0
    seg = np.clip(np.searchsorted(a, s_app) - 1, 0, len(slopes) - 1)
    scale = slopes[seg]
    after = s_app > a[-1]
    out[after] = d[-1] + k_end * (s_app[after] - a[-1])
    scale[after] = k_end
    before = s_app < a[0]
    out[before] = s_app[before] + (d[0] - a[0])
    scale[before] = 1.0
    return out, scale


def correct_stations(s_app: np.ndarray, rho_exp: np.ndarray, alignment: Alignment, s0_m: float,
                     passes: int = 1, windows: str = "curve"):
    """Curvature-matched stations: match the curve entries and exits (Eq. 41-43), re-map linearly
    from the known start, optionally repeat on the re-mapped stations (see the module docstring).

    Returns
    -------
    s, scale, anchors_app, anchors_design, ne2
    """
    s = s_app.copy()
    scale = np.ones_like(s_app)
    A = D = N = np.array([])
    for _ in range(passes):
        a, d, n = match_curves(s, rho_exp, alignment, windows=windows)
        if len(a) == 0:
            break
        s_new, k = remap(s, np.concatenate([[s0_m], a]), np.concatenate([[s0_m], d]))
        # anchors expressed in encoder stations (through the previous mapping)
        A = np.interp(a, s, s_app)
        D, N = d, n
        s, scale = s_new, scale * k
    return s, scale, A, D, N


ODOMETRY_METHODS = ("fused", "heading", "anchors")


def odometry(t_grid: np.ndarray, t_enc: np.ndarray, counts: np.ndarray, metres_per_count: float,
             s0_m: float, omega_z: np.ndarray | None, alignment: Alignment | None,
             min_speed_m_s: float = 3.0, match: bool = True, windows: str = "curve",
             method: str = "fused") -> Odometry:
    """Station, speed and acceleration of the TGMS on the processing grid (Escalona 2021 Sec. 8).

    Parameters
    ----------
    t_grid : uniform processing times.
    t_enc, counts : encoder samples; metres_per_count, s0_m : encoder scale and start station.
    omega_z : gyro z rate on ``t_grid`` (for Eq. 40); None disables matching.
    alignment : design (for the curvature functions).
    min_speed_m_s : slower samples are not used for rho_exp: the vehicle's yaw oscillation
        divided by a small V dominates Eq. 40 during a start from rest (on 8 simulated rides the
        exit anchors' rms error fell from 0.106 to 0.087 m with 3 m/s instead of 1 m/s).
    windows : matching windows of the Eq. 41 anchors, see ``match_curves``.
    match : apply the matching.
    method : "fused" (default): one encoder scale error from the heading fit and the Eq. 41
        anchors combined by their variances; "heading": the heading fit alone; "anchors": the
        Eq. 41 anchors with the piecewise-linear re-mapping of Fig. 11 (as published). See the
        module docstring for the measured station errors of each.

    Returns
    -------
    Odometry

    References
    ----------
    Escalona 2021 Eq. 40-43 and Fig. 10-11.
    """
    if method not in ODOMETRY_METHODS:
        raise ValueError(f"method must be one of {ODOMETRY_METHODS}, got {method!r}")
    s_app, v, a = encoder_motion(t_grid, t_enc, counts, metres_per_count, s0_m)
    A = D = N = S = np.array([])
    k = sk = float("nan")
    hf = None
    if match and omega_z is not None and alignment is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.where(v > min_speed_m_s, omega_z / v, np.nan)       # Eq. 40
        if method == "anchors":
            s, scale, A, D, N = correct_stations(s_app, rho, alignment, s0_m, windows=windows)
        else:
            hf = heading_fit(t_grid, omega_z, s_app, alignment, s0_m)
            if method == "fused":
                A, D, N, S = match_curves(s_app, rho, alignment, windows=windows, with_sigma=True)
                k, sk = fused_scale_error(hf, A, D, S, s0_m)
            else:
                k, sk = hf.scale_error, hf.sigma_scale_error
            # one scale for the ride: the wheel's rolling diameter (the encoder's error source)
            s = s0_m + (1.0 + k) * (s_app - s0_m)
            scale = np.full_like(s_app, 1.0 + k)
    else:
        s, scale = s_app.copy(), np.ones_like(s_app)
    return Odometry(t_s=t_grid, s_app_m=s_app, s_m=s, v_m_s=v * scale, a_m_s2=a * scale,
                    anchors_app_m=A, anchors_design_m=D, ne2_min=N, anchors_sigma_m=S,
                    scale_error=k, sigma_scale_error=sk, heading=hf)
