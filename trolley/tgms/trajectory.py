"""Trajectory of the TGMS relative to the design track frame, r_y(t), r_z(t) (Escalona 2021 Sec. 9).

The linear time-varying model of Eq. 46, written for the deviation dr = r - r0 from the nominal
offset r0 = [0, 0, delta] (delta: the TGMS height above the rail tops, FRD z < 0):

    dr'' = a_rel - (alpha~^t + omega~^t omega~^t) dr - 2 omega~^t dr'         (y, z rows of Eq. 44)
    a_rel = A^{t,tgms} f - f^d      (Eq. 45; f^d: specific force of the TF point r0, Briales Eq. 18)

with the accelerometer as the input and, against the instability of this double integrator, the
virtual measurements dr_y = 0, dr_z = 0 of Eq. 46's discussion (Gonzalez-Carbajal 2023 Eq. 14).
Their variance is set per sample so that the estimator's high-pass corner stays at a fixed
*wavelength* (``cutoff_wavelength_m``) whatever the speed: u_pos = q_a / (omega_c^4 dt),
omega_c = 2 pi V / lambda_c. A forward Kalman filter and RTS smoother give dr and its 1-sigma.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trolley.tgms.kalman import ltv_filter
from trolley.tgms.params import TgmsParams
from trolley.tgms.track import TrackKinematics


@dataclass
class RelativeTrajectory:
    """Deviation of the TGMS from its nominal offset r0, TF axes FRD (m), and 1-sigma."""

    dr_y_m: np.ndarray
    dr_z_m: np.ndarray
    sigma_y_m: np.ndarray
    sigma_z_m: np.ndarray
    loglik: float = float("nan")


def relative_acceleration(kin: TrackKinematics, f: np.ndarray, roll: np.ndarray, pitch: np.ndarray,
                          yaw: np.ndarray | None = None) -> np.ndarray:
    """a_rel (y, z) of Eq. 45-46: the specific force turned into the TF with the small relative
    angles, minus the design specific force of the nominal TGMS point. (n, 2)."""
    psi = np.zeros_like(roll) if yaw is None else yaw
    fx, fy, fz = f[:, 0], f[:, 1], f[:, 2]
    ay = fy + psi * fx - roll * fz - kin.f_design[:, 1]
    az = fz - pitch * fx + roll * fy - kin.f_design[:, 2]
    return np.column_stack([ay, az])


def trajectory_ltv(kin: TrackKinematics, f: np.ndarray, roll: np.ndarray, pitch: np.ndarray,
                   params: TgmsParams = TgmsParams(), smooth: bool = True,
                   min_speed_m_s: float = 2.0) -> RelativeTrajectory:
    """Relative trajectory by the LTV model of Escalona 2021 Eq. 46 with virtual zero-position
    measurements, Kalman filter and RTS smoother.

    Parameters
    ----------
    kin : design track kinematics (with f_design at the nominal offset r0).
    f : (n, 3) specific force on the processing grid.
    roll, pitch : relative attitude of the TGMS (from ``orientation``).
    params : accelerometer input noise density and cut-off wavelength.
    smooth : RTS smoothing.
    min_speed_m_s : floor of the speed used to set the virtual-measurement variance.

    Returns
    -------
    RelativeTrajectory

    References
    ----------
    Escalona 2021 Eq. 44-46 and Sec. 9 (method 2); Gonzalez-Carbajal 2023 Eq. 14.
    """
    n = len(kin.t_s)
    dt = float(kin.t_s[1] - kin.t_s[0])
    a = relative_acceleration(kin, f, roll, pitch)
    wx, wy, wz = kin.omega_t.T
    ax = kin.alpha_t[:, 0]
    A = np.zeros((n, 4, 4))
    A[:, 0, 1] = 1.0
    A[:, 2, 3] = 1.0
    A[:, 1, 0] = wx ** 2 + wz ** 2
    A[:, 1, 2] = -(wy * wz - ax)
    A[:, 1, 3] = 2 * wx
    A[:, 3, 0] = -(wy * wz + ax)
    A[:, 3, 1] = -2 * wx
    A[:, 3, 2] = wx ** 2 + wy ** 2
    F = np.eye(4) + A * dt + A @ A * (dt * dt / 2)
    G = np.array([[dt * dt / 2, 0.0], [dt, 0.0], [0.0, dt * dt / 2], [0.0, dt]])
    am = np.vstack([0.5 * (a[:-1] + a[1:]), a[-1:]])     # interval mean (see orientation.attitude_kf)
    Bu = am @ G.T
    qa = params.accel_noise_m_s2_sqrt_hz ** 2 / dt          # variance of one averaged sample
    Q = G @ G.T * qa
    H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    v = np.maximum(kin.v_m_s, min_speed_m_s)
    wc = 2 * np.pi * v / params.cutoff_wavelength_m
    upos = params.accel_noise_m_s2_sqrt_hz ** 2 / (wc ** 4 * dt)
    R = np.zeros((n, 2, 2))
    R[:, 0, 0] = R[:, 1, 1] = upos
    z = np.zeros((n, 2))
    P0 = np.diag([1e-4, 1e-4, 1e-4, 1e-4])
    res = ltv_filter(np.zeros(4), P0, F, Bu, Q, H, R, z, smooth=smooth)
    x, P = (res.x_s, res.P_s) if smooth else (res.x_f, res.P_f)
    return RelativeTrajectory(dr_y_m=x[:, 0], dr_z_m=x[:, 2], sigma_y_m=np.sqrt(P[:, 0, 0]),
                              sigma_z_m=np.sqrt(P[:, 2, 2]), loglik=res.loglik)
