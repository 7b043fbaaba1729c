"""Track preprocessor (Escalona 2021 Sec. 3.2): design track-frame kinematics along a ride.

Given the design :class:`trolley.alignment.Alignment` and the TGMS station s(t) on a uniform time
grid, this returns what the estimators need at every instant: the track-frame (TF) attitude, its
angular velocity omega^t (Eq. 5) and angular acceleration alpha^t, the curvatures, and the specific
force that an IMU rigidly fixed to the TF at the nominal TGMS offset r0 = [0, 0, delta] would
measure, i.e. R''^t + (alpha~^t + omega~^t omega~^t) r0 minus gravity, projected on the TF
(Eq. 4 with Briales Eq. 18). These are obtained by differentiating the exact design pose
numerically on the time grid, which also keeps the rho_tw' and rho_v' terms that Eq. 5 drops (the
cant ramps of a design are only C0, so they are impulses that a real IMU does feel).

The TF here is FRD (see ``trolley.tgms``): attitude = yaw heading, pitch slope, roll cant (ZYX).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from trolley.alignment import Alignment

#: Gravity used by the TGMS models, m/s^2.
GRAVITY_M_S2 = 9.80665


def track_rotation(heading_rad, slope_rad, cant_rad) -> Rotation:
    """Rotation from TF (FRD) to NED: yaw = heading, pitch = slope, roll = cant (Escalona Eq. 2)."""
    return Rotation.from_euler("ZYX", np.column_stack([heading_rad, slope_rad, cant_rad]))


def ned_position(sample) -> np.ndarray:
    """(n, 3) NED position of the design centre line from an AlignmentSample."""
    return np.column_stack([sample.N_m, sample.E_m, -sample.H_m])


def angular_velocity_body(R: Rotation, dt: float) -> np.ndarray:
    """Angular velocity (body axes) of a sampled attitude history, central differences, (n, 3)."""
    n = len(R)
    w = np.empty((n, 3))
    rv = (R[:-1].inv() * R[1:]).as_rotvec() / dt        # mid-interval rates
    w[1:-1] = 0.5 * (rv[:-1] + rv[1:])
    w[0], w[-1] = rv[0], rv[-1]
    return w


@dataclass
class TrackKinematics:
    """Design track-frame kinematics along a ride (arrays over the time grid).

    Attributes
    ----------
    t_s, s_m, v_m_s, a_m_s2 : time, station, forward speed dV/dt... (V and V').
    rho_h, drho_h, rho_v, rho_tw : curvatures (1/m, 1/m^2), FRD signs.
    heading_rad, slope_rad, cant_rad : TF attitude (yaw, pitch, roll).
    omega_t : (n, 3) angular velocity of the TF in TF axes, rad/s (Eq. 5).
    alpha_t : (n, 3) angular acceleration of the TF in TF axes, rad/s^2.
    f_design : (n, 3) specific force of a point fixed in the TF at r0, TF axes, m/s^2.
    """

    t_s: np.ndarray
    s_m: np.ndarray
    v_m_s: np.ndarray
    a_m_s2: np.ndarray
    rho_h: np.ndarray
    drho_h: np.ndarray
    rho_v: np.ndarray
    rho_tw: np.ndarray
    heading_rad: np.ndarray
    slope_rad: np.ndarray
    cant_rad: np.ndarray
    omega_t: np.ndarray
    alpha_t: np.ndarray
    f_design: np.ndarray


def track_kinematics(alignment: Alignment, t_s: np.ndarray, s_m: np.ndarray,
                     r0_m: np.ndarray = np.zeros(3)) -> TrackKinematics:
    """Design TF kinematics along the ride s(t) on a uniform time grid.

    Parameters
    ----------
    alignment : design geometry.
    t_s : (n,) uniform times, s.
    s_m : (n,) station of the TGMS at those times, m (smooth; e.g. from the odometry).
    r0_m : (3,) nominal TGMS offset from the TF origin, TF axes (e.g. [0, 0, -0.45]: 0.45 m above
        the rail tops), m.

    Returns
    -------
    TrackKinematics

    References
    ----------
    Escalona 2021 Eq. 2-5; Briales Eq. 13 and 18.
    """
    dt = float(t_s[1] - t_s[0])
    g = alignment.evaluate(s_m)
    R = track_rotation(g.heading_rad, g.slope_rad, g.cant_rad)
    p = ned_position(g) + R.apply(r0_m)
    acc = np.gradient(np.gradient(p, dt, axis=0), dt, axis=0)
    f_ned = acc - np.array([0.0, 0.0, GRAVITY_M_S2])
    f_tf = R.inv().apply(f_ned)
    w = angular_velocity_body(R, dt)
    alpha = np.gradient(w, dt, axis=0)
    v = np.gradient(s_m, dt)
    a = np.gradient(v, dt)
    return TrackKinematics(t_s=t_s, s_m=s_m, v_m_s=v, a_m_s2=a, rho_h=g.rho_h_1_m,
                           drho_h=g.drho_h_ds_1_m2, rho_v=g.rho_v_1_m, rho_tw=g.rho_tw_1_m,
                           heading_rad=g.heading_rad, slope_rad=g.slope_rad, cant_rad=g.cant_rad,
                           omega_t=w, alpha_t=alpha, f_design=f_tf)
