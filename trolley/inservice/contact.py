"""Nonlinear wheel-rail contact of the in-service truth simulator (one wheelset, both wheels).

This is the contact of the *complete* model (Munoz 2021 Sec. III-B: equivalent conicity, knife-edge
contact, Kalker creep, flange contact), made deliberately richer than the estimator's linear
Kalker/conical model (Sec. III-C, Eq. 3-4) so that the validation is not self-referential:

* **Profile**: rolling-radius difference of a worn-like profile pair that is not a pure cone,
  Delta r(y) = r_L - r_R = 2 lambda0 (y + y^3 / y_c^2) for the wheelset's lateral shift y relative
  to the rails (positive left). The local conicity d(Delta r / 2)/dy = lambda0 (1 + 3 y^2 / y_c^2)
  and the UIC 519 equivalent conicity of a harmonic motion of amplitude A (the first Fourier
  coefficient of Delta r(A sin wt) / 2A, the describing function) is
  lambda_e(A) = lambda0 (1 + 3 A^2 / (4 y_c^2)): lambda0 at A = 0 and rising with the shift, as the
  equivalent conicity of S1002 wheels on UIC60 1:40 rails does (about 0.15-0.2 at 3 mm).
* **Gravitational stiffness**: the contact plane rolls by Delta r / (2 b) (knife-edge rails), so the
  resultant of the wheel loads N_L + N_R gets the lateral component -(N_L + N_R) Delta r / (2 b);
  a cross level (left rail higher by c) adds -(N_L + N_R) c / (2 b) (Wickens 2003, Sec. 2.5).
* **Creepages** (track frame: x forward, y left, yaw counter-clockwise; design curvature kappa
  positive to the left; spin neglected), for the left / right wheel::

      nu_x = -+ (b kappa + b psi' / V + Delta r / (2 r0)),     nu_y = y' / V - psi

  (the rail's own slope cancels between the lateral velocity and the yaw relative to the rail).
* **Creep forces**: Kalker's linear coefficients scaled with the wheel load as f (N / N0)^(2/3)
  (the contact ellipse area grows as N^(2/3), Hertz), F = -f nu, then saturated to the Coulomb
  limit mu N with Shen-Hedrick-Elkins: with beta = |F_lin| / (mu N), the forces are multiplied by
  (beta - beta^2 / 3 + beta^3 / 27) / beta for beta <= 3 and by 1 / beta beyond.
* **Flange contact**: a lateral spring of the rail, -k_f (|y| - delta) sign(y) beyond the flangeway
  clearance delta (deadband model of Cooperrider 1972 used by True: delta = 9.1 mm,
  k_f = 14.6 MN/m).

References
----------
S. Munoz et al., IEEE Access 9 (2021) 60010-60025, Sec. III-B/C.
Z. Y. Shen, J. K. Hedrick, J. A. Elkins, "A comparison of alternative creep force models for rail
vehicle dynamic analysis", Vehicle System Dynamics 12 (1983) 79-83.
J. J. Kalker, "A fast algorithm for the simplified theory of rolling contact", VSD 11 (1982) 1-13.
A. H. Wickens, Fundamentals of Rail Vehicle Dynamics, Swets & Zeitlinger 2003 (creepages,
gravitational stiffness). UIC 519 (2004): equivalent conicity as harmonic linearisation.
N. K. Cooperrider, "The hunting behavior of conventional railway trucks", ASME J. Eng. Ind. 94
(1972) 752-762 (flange deadband and rail stiffness).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ContactParameters:
    """Wheel-rail contact of one wheelset (SI).

    Attributes
    ----------
    r0 : centred rolling radius, m.
    b : half distance between the contact points, m.
    conicity : lambda0, the conicity of small shifts.
    conicity_growth_m : y_c of the profile law (module docstring); the conicity doubles at y_c / sqrt 3.
    f11, f22 : Kalker's longitudinal and lateral creep coefficients per wheel at the load N0, N.
    wheel_load_n : N0, the static wheel load the coefficients refer to, N.
    mu : friction coefficient.
    flange_clearance_m, flange_stiffness_n_m : flangeway clearance delta and rail lateral stiffness k_f.
    """

    r0: float = 0.46
    b: float = 0.75
    conicity: float = 0.15
    conicity_growth_m: float = 6.0e-3
    f11: float = 1.0e7
    f22: float = 8.7e6
    wheel_load_n: float = 54.5e3
    mu: float = 0.3
    flange_clearance_m: float = 9.1e-3
    flange_stiffness_n_m: float = 14.6e6


def rolling_radius_difference(y_m, p: ContactParameters) -> np.ndarray:
    """Delta r = r_L - r_R for the lateral shift y of the wheelset relative to the rails, m."""
    y = np.asarray(y_m, float)
    return 2.0 * p.conicity * (y + y ** 3 / p.conicity_growth_m ** 2)


def local_conicity(y_m, p: ContactParameters) -> np.ndarray:
    """d(Delta r / 2) / dy at the shift y (lambda0 at y = 0)."""
    y = np.asarray(y_m, float)
    return p.conicity * (1.0 + 3.0 * y ** 2 / p.conicity_growth_m ** 2)


def equivalent_conicity(amplitude_m, p: ContactParameters) -> np.ndarray:
    """UIC 519 equivalent conicity of a harmonic lateral motion of amplitude A (harmonic linearisation).

    lambda_e(A) = (1 / (pi A)) int_0^{2 pi} Delta r(A sin t) / 2 sin t dt = lambda0 (1 + 3 A^2 / (4 y_c^2)).
    """
    a = np.asarray(amplitude_m, float)
    return p.conicity * (1.0 + 0.75 * a ** 2 / p.conicity_growth_m ** 2)


def flange_force(y_m, p: ContactParameters) -> np.ndarray:
    """Lateral force of the rails on the flanges, N: -k_f (|y| - delta) sign(y) beyond the clearance."""
    y = np.asarray(y_m, float)
    over = np.maximum(np.abs(y) - p.flange_clearance_m, 0.0)
    return -p.flange_stiffness_n_m * over * np.sign(y)


def saturation_factor(force_lin_n, limit_n) -> np.ndarray:
    """Shen-Hedrick-Elkins factor eps with |F| = eps |F_lin| <= mu N (1 for small creep).

    Parameters
    ----------
    force_lin_n : magnitude of the linear (Kalker) creep force, N (>= 0).
    limit_n : Coulomb limit mu N, N (>= 0; 0 gives 0: an unloaded wheel transmits nothing).
    """
    f = np.asarray(force_lin_n, float)
    lim = np.asarray(limit_n, float)
    beta = f / np.maximum(lim, 1e-200)  # lim = 0: beta huge, eps = 1 / beta ~ 0
    b3 = np.minimum(beta, 3.0)
    # 1 - b/3 + b^2/27 up to beta = 3 (where it is 1/3), then 1/beta: one expression, no division by 0
    return (1.0 - b3 / 3.0 + b3 * b3 / 27.0) * (3.0 / np.maximum(beta, 3.0))


def creep_forces(nu_x, nu_y, normal_n, p: ContactParameters, creep_factor: float = 1.0):
    """Saturated creep forces of one wheel (force of the rail on the wheel), N.

    Parameters
    ----------
    nu_x, nu_y : longitudinal and lateral creepages.
    normal_n : wheel load N (negative values are treated as 0: the wheel has lifted).
    p : contact parameters (f11, f22 at N0, mu).
    creep_factor : multiplier of the Kalker coefficients (robustness study: 0.5).

    Returns
    -------
    (F_x, F_y) arrays.
    """
    n = np.maximum(np.asarray(normal_n, float), 0.0)
    scale = creep_factor * (n / p.wheel_load_n) ** (2.0 / 3.0)
    fx = -p.f11 * scale * nu_x
    fy = -p.f22 * scale * nu_y
    eps = saturation_factor(np.hypot(fx, fy), p.mu * n)
    return eps * fx, eps * fy


def wheelset_forces(y_rel_m, vy_m_s, psi_rad, wz_rad_s, normal_left_n, normal_right_n, cross_level_m,
                    speed_m_s: float, curvature_1_m: float, p: ContactParameters, creep_factor: float = 1.0):
    """Lateral force and yaw moment of the rails on a wheelset (vectorised over wheelsets / time).

    Parameters
    ----------
    y_rel_m : lateral shift of the wheelset relative to the rails' centre line (y - xi), m.
    vy_m_s, psi_rad, wz_rad_s : lateral velocity, yaw and yaw rate relative to the design track frame.
    normal_left_n, normal_right_n : wheel loads, N.
    cross_level_m : left rail minus right rail height, m.
    speed_m_s : V; curvature_1_m : design curvature kappa (left positive).
    p : contact parameters; creep_factor : Kalker multiplier.

    Returns
    -------
    (F_y, M_z) : lateral force (N, left positive) and yaw moment (N m, counter-clockwise positive).
    """
    dr = rolling_radius_difference(y_rel_m, p)
    nux_l = np.atleast_1d(-(p.b * curvature_1_m + p.b * wz_rad_s / speed_m_s + dr / (2.0 * p.r0)))
    nuy = np.broadcast_to(vy_m_s / speed_m_s - psi_rad, nux_l.shape)
    normal_left_n = np.broadcast_to(normal_left_n, nux_l.shape)
    normal_right_n = np.broadcast_to(normal_right_n, nux_l.shape)
    # both wheels in one call: left on the first half, right on the second
    fx, fy = creep_forces(np.concatenate([nux_l, -nux_l]), np.concatenate([nuy, nuy]),
                          np.concatenate([normal_left_n, normal_right_n]), p, creep_factor)
    n = len(nux_l)
    n_sum = np.maximum(normal_left_n, 0.0) + np.maximum(normal_right_n, 0.0)
    fy_total = fy[:n] + fy[n:] - n_sum * (dr + cross_level_m) / (2.0 * p.b) + flange_force(y_rel_m, p)
    return fy_total, p.b * (fx[n:] - fx[:n])
