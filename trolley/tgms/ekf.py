"""The 12-state extended Kalman smoother of Gonzalez-Carbajal 2023 (Sec. 3, Appendix 1).

State (Eq. 15): x = [phi, phi', theta, theta', psi, psi', r_y, r_y', r_y'', r_z, r_z', r_z''] with
absolute Euler angles of the TGMS (ZYX, FRD) and its position relative to the design track frame
(here the deviation dr from the nominal offset r0, TF axes FRD). Process model (Appendix 1):
Wiener-process angular accelerations (blocks F1, Q1 with q_phi, q_theta, q_psi) and Wiener-process
jerks (F2, Q2 with q_y, q_z). Measurements (Appendix 1, z): the three gyro rates (Eq. 7), the three
accelerometer components (Eq. 11-12) and the virtual positions (Eq. 14), with the diagonal U.

Differences from the printed appendix, on purpose:

* the frame is FRD and the measurement function is evaluated exactly instead of with the
  expanded small-angle terms g_4A..g_6E: gyro = Euler-rate matrix (Eq. 7) times the angle rates;
  accelerometer = (A^{t,b})^T (f^d + r'' + (alpha~ + omega~ omega~) dr + 2 omega~ r'), with
  A^{t,b} = (A^t)^T A^b from the absolute and design angles (Eq. 5, 9) and f^d the design specific
  force at r0 (``track``), which already holds R''^t and gravity;
* the Jacobian J is computed by central differences of that function (the printed J has
  typesetting slips, e.g. J_4,3 carries rho_v V for rho_v V^2, and J_5,10 a misplaced bracket);
* u_pos follows the speed, u_pos(V) = u_pos(10 m/s) (10 m/s / V)^4, so that the virtual
  measurements act at a fixed wavelength (as in ``trajectory``); one q for the three angles, one
  for the two jerks, one u for the three accelerometer axes.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from trolley.tgms.kalman import rts
from trolley.tgms.orientation import RelativeAttitude
from trolley.tgms.params import TgmsParams
from trolley.tgms.track import TrackKinematics, track_rotation
from trolley.tgms.trajectory import RelativeTrajectory


def _euler_matrix(a):
    """(n, 3, 3) rotation matrices (body -> NED) from (n, 3) [roll, pitch, yaw]."""
    return Rotation.from_euler("ZYX", a[:, ::-1]).as_matrix()


def measurement(X: np.ndarray, Ct: np.ndarray, fd: np.ndarray, w_t: np.ndarray, al_t: np.ndarray) -> np.ndarray:
    """Measurement function h(x) for a batch of states X (b, 12) at one instant: gyro (3), accel (3),
    virtual positions (2). Ct: TF -> NED matrix; fd, w_t, al_t: design specific force, TF angular
    velocity and acceleration (TF axes)."""
    phi, dphi, th, dth, psi, dpsi = (X[:, i] for i in range(6))
    ry, vy, ay, rz, vz, az = (X[:, i] for i in range(6, 12))
    sp, cp, st, ct = np.sin(phi), np.cos(phi), np.sin(th), np.cos(th)
    gx = dphi - st * dpsi                           # Gonzalez-Carbajal 2023 Eq. 7 (exact)
    gy = cp * dth + sp * ct * dpsi
    gz = -sp * dth + cp * ct * dpsi
    Cb = _euler_matrix(np.column_stack([phi, th, psi]))
    Arel = np.einsum("ji,bjk->bik", Ct, Cb)          # A^{t,b} = (A^t)^T A^b  (Eq. 5)
    r = np.column_stack([np.zeros_like(ry), ry, rz])
    v = np.column_stack([np.zeros_like(ry), vy, vz])
    a = np.column_stack([np.zeros_like(ry), ay, az])
    rel = a + np.cross(al_t, r) + np.cross(w_t, np.cross(w_t, r)) + 2 * np.cross(w_t, v)   # Eq. 12
    f = np.einsum("bji,bj->bi", Arel, fd[None, :] + rel)                                # Eq. 11
    return np.column_stack([gx, gy, gz, f, ry, rz])


#: Central-difference steps of the Jacobian, per state (rad, rad/s; m, m/s, m/s^2).
JACOBIAN_STEPS = np.array([1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-5, 1e-5, 1e-4, 1e-5, 1e-5, 1e-4])


def measurement_jacobian(x: np.ndarray, Ct: np.ndarray, fd: np.ndarray, w_t: np.ndarray, al_t: np.ndarray,
                         eps: np.ndarray = JACOBIAN_STEPS):
    """h(x) and its Jacobian J = dh/dx (8, 12) by central differences (one batched call of
    :func:`measurement`), the J of Gonzalez-Carbajal 2023 Appendix 1 without its typesetting slips."""
    E = np.diag(eps)
    hx = measurement(np.vstack([x[None, :], x + E, x - E]), Ct, fd, w_t, al_t)
    return hx[0], ((hx[1:13] - hx[13:25]) / (2 * eps[:, None])).T


def _process(dt: float, p: TgmsParams, q):
    F1 = np.array([[1.0, dt], [0.0, 1.0]])
    F2 = np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    Q1 = np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    Q2 = np.array([[dt ** 5 / 20, dt ** 4 / 8, dt ** 3 / 6], [dt ** 4 / 8, dt ** 3 / 3, dt ** 2 / 2],
                   [dt ** 3 / 6, dt ** 2 / 2, dt]])
    F = np.zeros((12, 12))
    Q = np.zeros((12, 12))
    for k, (sl, Fb, Qb, qq) in enumerate(((slice(0, 2), F1, Q1, q[0]), (slice(2, 4), F1, Q1, q[1]),
                                          (slice(4, 6), F1, Q1, q[2]), (slice(6, 9), F2, Q2, q[3]),
                                          (slice(9, 12), F2, Q2, q[4]))):
        F[sl, sl] = Fb
        Q[sl, sl] = qq * Qb
    return F, Q


def trajectory_ekf(kin: TrackKinematics, w: np.ndarray, f: np.ndarray, att0: RelativeAttitude | None = None,
                   params: TgmsParams = TgmsParams(), min_speed_m_s: float = 2.0, smooth: bool = True):
    """12-state extended Kalman filter + RTS smoother (Gonzalez-Carbajal 2023 Appendix 1).

    Parameters
    ----------
    kin : design track kinematics (f_design at the nominal offset).
    w, f : (n, 3) gyro and accelerometer on the processing grid.
    att0 : unused except for its first sample as the initial relative attitude (may be None).
    params : ekf_q_angle_rad2_s3, ekf_q_jerk_m2_s5 (Q), gyro_noise_rad_sqrt_s, ekf_u_acc_m2_s4,
        ekf_u_pos_m2 (U), see TgmsParams.
    smooth : RTS smoothing.

    Returns
    -------
    RelativeTrajectory, with ``.attitude`` (RelativeAttitude, relative roll and pitch) attached.

    References
    ----------
    Gonzalez-Carbajal 2023 Eq. 7, 9, 11-15 and Appendix 1.
    """
    n = len(kin.t_s)
    dt = float(kin.t_s[1] - kin.t_s[0])
    qa, qj = params.ekf_q_angle_rad2_s3, params.ekf_q_jerk_m2_s5
    F, Q = _process(dt, params, (qa, qa, qa, qj, qj))
    Ct = track_rotation(kin.heading_rad, kin.slope_rad, kin.cant_rad).as_matrix()
    u_w = params.gyro_noise_rad_sqrt_s ** 2 / dt
    u_a = params.ekf_u_acc_m2_s4
    v = np.maximum(kin.v_m_s, min_speed_m_s)
    u_pos = params.ekf_u_pos_m2 * (10.0 / v) ** 4
    z = np.column_stack([w, f, np.zeros((n, 2))])
    x = np.zeros(12)
    x[0], x[2], x[4] = kin.cant_rad[0], kin.slope_rad[0], kin.heading_rad[0]
    if att0 is not None:
        x[0] += att0.roll_rad[0]
        x[2] += att0.pitch_rad[0]
    P = np.diag([1e-4, 1e-6, 1e-4, 1e-6, 1e-4, 1e-6, 1e-4, 1e-4, 1e-2, 1e-4, 1e-4, 1e-2])
    xf = np.empty((n, 12))
    Pf = np.empty((n, 12, 12))
    I = np.eye(12)
    ll = 0.0
    for i in range(n):
        if i > 0:
            x = F @ x
            P = F @ P @ F.T + Q
        h0, H = measurement_jacobian(x, Ct[i], kin.f_design[i], kin.omega_t[i], kin.alpha_t[i])
        R = np.diag([u_w, u_w, u_w, u_a, u_a, u_a, u_pos[i], u_pos[i]])
        y = z[i] - h0
        PHt = P @ H.T
        S = H @ PHt + R
        Si = np.linalg.inv(S)
        K = PHt @ Si
        x = x + K @ y
        IKH = I - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T
        sign, logdet = np.linalg.slogdet(S)
        ll -= 0.5 * (y @ Si @ y + logdet + 8 * np.log(2 * np.pi))
        xf[i] = x
        Pf[i] = P
    if smooth:
        xs, Ps = rts(xf, Pf, np.broadcast_to(F, (n, 12, 12)), np.zeros((n, 12)), np.broadcast_to(Q, (n, 12, 12)))
    else:
        xs, Ps = xf, Pf
    # relative attitude (Eq. 9, exact): A^{t,b} = (A^t)^T A^b
    Cb = _euler_matrix(xs[:, [0, 2, 4]])
    rel = Rotation.from_matrix(np.einsum("nji,njk->nik", Ct, Cb)).as_euler("ZYX")
    att = RelativeAttitude(roll_rad=rel[:, 2], pitch_rad=rel[:, 1], sigma_roll_rad=np.sqrt(Ps[:, 0, 0]),
                           sigma_pitch_rad=np.sqrt(Ps[:, 2, 2]), bias_rad_s=np.zeros((n, 2)), loglik=ll,
                           yaw_rad=rel[:, 0])
    tr = RelativeTrajectory(dr_y_m=xs[:, 6], dr_z_m=xs[:, 9], sigma_y_m=np.sqrt(Ps[:, 6, 6]),
                            sigma_z_m=np.sqrt(Ps[:, 9, 9]), loglik=ll)
    tr.attitude = att
    return tr
