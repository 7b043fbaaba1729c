"""Roll and pitch of the TGMS relative to the track frame (Escalona 2021 Sec. 7).

Both estimators work on the *relative* angles (phi, theta) of the TGMS with respect to the design
track frame, which stay small (mrad) even in canted curves, so the small-angle model is accurate:

* gyro (Eq. 32 with Eq. 15): phi' = (w_x - b_x) - w^t_x + w^t_z theta,
  theta' = (w_y - b_y) - w^t_y - w^t_z phi, i.e. the transition matrix F = [[0, w_z], [-w_z, 0]]
  of Eq. 39 driven by the gyro rates minus the track-frame rates w^t;
* accelerometer (Eq. 38, Briales Eq. 18): the specific force of a point fixed in the TF at the
  nominal TGMS offset, f^d (``track.track_kinematics``), is subtracted; what is left is the tilt of
  gravity, z = f - f^d = [-f^d_z theta, f^d_z phi] (= [g theta, -g phi] in FRD).

:func:`attitude_kf` is the Kalman filter of Eq. 39 augmented with two gyro-bias states, followed
by RTS smoothing. :func:`attitude_madgwick` is the gradient-descent variant of Briales Sec. 5.2:
the gyro-integrated attitude is corrected each step by a fixed-rate step beta along the normalised
gradient of the track-compensated objective (Briales Eq. 42), with Madgwick's gyro-bias feedback,
started from the window-averaged accelerometer attitude (see its docstring for why).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trolley.tgms.kalman import ltv_filter
from trolley.tgms.params import TgmsParams
from trolley.tgms.track import TrackKinematics


@dataclass
class RelativeAttitude:
    """Relative roll and pitch of the TGMS (FRD, rad) on the processing grid, with 1-sigma
    (NaN for estimators without a covariance) and gyro-bias estimates (rad/s)."""

    roll_rad: np.ndarray
    pitch_rad: np.ndarray
    sigma_roll_rad: np.ndarray
    sigma_pitch_rad: np.ndarray
    bias_rad_s: np.ndarray
    loglik: float = float("nan")
    yaw_rad: np.ndarray | None = None


def _inputs(kin: TrackKinematics, w: np.ndarray, f: np.ndarray):
    u = w[:, :2] - kin.omega_t[:, :2]
    z = f[:, :2] - kin.f_design[:, :2]
    return u, z


def attitude_kf(kin: TrackKinematics, w: np.ndarray, f: np.ndarray, params: TgmsParams = TgmsParams(),
                smooth: bool = True) -> RelativeAttitude:
    """Kalman filter + RTS smoother of Escalona 2021 Eq. 39 on the relative angles.

    Parameters
    ----------
    kin : design track kinematics on the processing grid.
    w, f : (n, 3) gyro rates and specific forces averaged to the processing grid (TGMS frame).
    params : TgmsParams (gyro noise, bias random walk, accelerometer disturbance).
    smooth : RTS smoothing (otherwise the forward filter is returned).

    Returns
    -------
    RelativeAttitude

    References
    ----------
    Escalona 2021 Eq. 32, 38, 39; Briales Eq. 18.
    """
    n = len(kin.t_s)
    dt = float(kin.t_s[1] - kin.t_s[0])
    u, z = _inputs(kin, w, f)
    wz = kin.omega_t[:, 2]
    F = np.zeros((n, 4, 4))
    F[:] = np.eye(4)
    F[:, 0, 1] = wz * dt
    F[:, 1, 0] = -wz * dt
    F[:, 0, 2] = -dt
    F[:, 1, 3] = -dt
    # the processing samples are interval means centred on t_k: the step k -> k+1 integrates the
    # mean of the two (a half-sample lag otherwise, 5 ms at 100 Hz, is 8e-5 rad on a 2 Hz roll)
    um = np.vstack([0.5 * (u[:-1] + u[1:]), u[-1:]])
    Bu = np.column_stack([um * dt, np.zeros((n, 2))])
    qa = params.gyro_noise_rad_sqrt_s ** 2 * dt
    qb = params.gyro_bias_rw_rad_s_sqrt_s ** 2 * dt
    Q = np.diag([qa, qa, qb, qb])
    fz = kin.f_design[:, 2]
    H = np.zeros((n, 2, 4))
    H[:, 0, 1] = -fz
    H[:, 1, 0] = fz
    R = np.eye(2) * params.accel_disturbance_m_s2 ** 2
    x0 = np.array([z[0, 1] / fz[0], -z[0, 0] / fz[0], 0.0, 0.0])
    P0 = np.diag([1e-4, 1e-4, 1e-8, 1e-8])
    res = ltv_filter(x0, P0, F, Bu, Q, H, R, z, smooth=smooth)
    x, P = (res.x_s, res.P_s) if smooth else (res.x_f, res.P_f)
    return RelativeAttitude(roll_rad=x[:, 0], pitch_rad=x[:, 1],
                            sigma_roll_rad=np.sqrt(P[:, 0, 0]), sigma_pitch_rad=np.sqrt(P[:, 1, 1]),
                            bias_rad_s=x[:, 2:], loglik=res.loglik)


def _accel_angles(z: np.ndarray, fz: np.ndarray) -> np.ndarray:
    """(phi, theta) that zero the residual of the track-compensated measurement model
    z = [-f^d_z theta, f^d_z phi] (Escalona Eq. 38, Briales Eq. 18), per sample."""
    return np.column_stack([z[:, 1] / fz, -z[:, 0] / fz])


def _madgwick_gradient(x: np.ndarray, z: np.ndarray, fz: float) -> np.ndarray:
    """Gradient of J(x) = |z - h(x)|^2 / 2 with h(x) = [-f^d_z theta, f^d_z phi] (Briales Eq. 42 in
    the small relative angles): dJ/dx = -(dh/dx)^T (z - h(x)), dh/dx = [[0, -f_z], [f_z, 0]]."""
    e = z - np.array([-fz * x[1], fz * x[0]])
    return -np.array([fz * e[1], -fz * e[0]])


def attitude_madgwick(kin: TrackKinematics, w: np.ndarray, f: np.ndarray,
                      params: TgmsParams = TgmsParams(), init_window_s: float = 2.0) -> RelativeAttitude:
    """Gradient-descent (Madgwick-style) relative attitude of Briales Sec. 5.2.

    Each step integrates the track-relative gyro rates and subtracts beta times the normalised
    gradient of |z - h(x)|^2 / 2 with the track-compensated accelerations (Briales Eq. 42); the gyro
    bias follows Madgwick's drift compensation with gain zeta. The recursion is run forward and
    backward in time (with reversed rates) and the two passes averaged, so the result has no lag.

    Each pass starts from the attitude that zeroes the compensated residual (Eq. 42) *on average*
    over its first ``init_window_s`` seconds. The normalised step corrects at most beta rad/s
    (3e-4 by default), so a start from one sample, whose lateral specific force carries the body's
    sway (0.45 m/s^2 std at rest in the simulator, i.e. 0.02-0.05 rad of apparent roll), took
    longer than a 300 m ride to decay: a roll ramp of ~4e-4 rad/s that Eq. 46 integrated into
    0.4-1.3 mm of alignment error. Averaging over 2 s (several periods of the 0.3-3 Hz body modes)
    leaves ~1e-3 rad, removed in seconds; measured on the six benchmark rides, 2-5 s give the same
    accuracy, 1 s and 0.5 s are worse (alignment worst case 0.31, 0.58 mm against 0.27).

    Parameters
    ----------
    kin : design track kinematics on the processing grid.
    w, f : (n, 3) gyro rates and specific forces averaged to the processing grid (TGMS frame).
    params : TgmsParams (madgwick_beta_rad_s, madgwick_zeta_rad_s2).
    init_window_s : averaging window of the initial attitude of each pass.

    Returns
    -------
    RelativeAttitude (no covariance: sigma NaN).

    References
    ----------
    Briales Sec. 5.2, Eq. 40-42; Madgwick et al. (2011).
    """
    n = len(kin.t_s)
    dt = float(kin.t_s[1] - kin.t_s[0])
    u, z = _inputs(kin, w, f)
    wz = kin.omega_t[:, 2]
    fz = kin.f_design[:, 2]
    beta, zeta = params.madgwick_beta_rad_s, params.madgwick_zeta_rad_s2

    acc = _accel_angles(z, fz)
    k0 = int(np.clip(round(init_window_s / dt), 1, n))

    def run(order, sign, x0):
        x = x0.copy()
        b = np.zeros(2)
        out = np.empty((n, 2))
        for i in order:
            grad = _madgwick_gradient(x, z[i], fz[i])
            ng = np.hypot(grad[0], grad[1])
            step = grad / ng if ng > 0 else grad
            b = b + sign * zeta * dt * step
            rate = u[i] - b + np.array([wz[i] * x[1], -wz[i] * x[0]])
            x = x + sign * rate * dt - beta * dt * step
            out[i] = x
        return out

    fwd = run(range(n), 1.0, acc[:k0].mean(axis=0))
    bwd = run(range(n - 1, -1, -1), -1.0, acc[n - k0:].mean(axis=0))
    x = 0.5 * (fwd + bwd)
    nan = np.full(n, np.nan)
    return RelativeAttitude(roll_rad=x[:, 0], pitch_rad=x[:, 1], sigma_roll_rad=nan,
                            sigma_pitch_rad=nan.copy(), bias_rad_s=np.zeros((n, 2)))


def relative_yaw(kin: TrackKinematics, w: np.ndarray, params: TgmsParams = TgmsParams(),
                 min_speed_m_s: float = 2.0) -> np.ndarray:
    """Relative yaw psi of the TGMS (rad): the gyro's yaw rate minus the track frame's, integrated
    (Escalona 2021 Eq. 32, third row, with Eq. 15) by a Kalman filter + RTS smoother whose
    virtual zero measurements (variance following the speed, as in ``trajectory``) remove the
    drift beyond ``cutoff_wavelength_m``. Used only for the laser planes' lever arm ahead of the
    IMU (psi x_L), which the relative-attitude filter of Eq. 39 does not provide.
    """
    n = len(kin.t_s)
    dt = float(kin.t_s[1] - kin.t_s[0])
    u = w[:, 2] - kin.omega_t[:, 2]
    um = np.concatenate([0.5 * (u[:-1] + u[1:]), u[-1:]])
    q = params.gyro_noise_rad_sqrt_s ** 2 * dt
    v = np.maximum(kin.v_m_s, min_speed_m_s)
    wc = 2 * np.pi * v / params.cutoff_wavelength_m
    R = (params.gyro_noise_rad_sqrt_s ** 2 / (wc ** 2 * dt))[:, None, None]
    res = ltv_filter(np.zeros(1), np.eye(1) * 1e-4, np.ones((1, 1)), (um * dt)[:, None], np.eye(1) * q,
                     np.ones((1, 1)), R, np.zeros((n, 1)))
    return res.x_s[:, 0]
