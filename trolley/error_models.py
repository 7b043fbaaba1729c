"""Reduced-order dead-reckoning error models of Jiang 2017, Sec. 3-4, and their discretisation.

Two channels, decoupled (Jiang 2017 Sec. 4.1):

* vertical channel, 3 states (Eq. 17-21)::

      x_v = [dr_D, phi_pitch_eq, gyro_bias_y_eq]
      A_v = [[0, v, 0], [0, 0, -1], [0, 0, 0]],   G_v = [0, 1, 0]^T,   H_v = [1, 0, 0]

* level channel, 5 states (Eq. 22-25)::

      x_l = [dr_N, dr_E, odo_scale_error, phi_D_eq, gyro_bias_z_eq]
      A_l = [[0, 0, v cos(psi),  v sin(psi), 0],
             [0, 0, v sin(psi), -v cos(psi), 0],
             [0, 0, 0, 0,  0],
             [0, 0, 0, 0, -1],
             [0, 0, 0, 0,  0]]
      G_l = [[0, 0], [0, 0], [1, 0], [0, 1], [0, 0]],   H_l = [[1, 0, 0, 0, 0], [0, 1, 0, 0, 0]]

The state is the error of the dead-reckoned solution: estimate minus truth. ``phi`` are the
equivalent attitude errors of Eq. 14 (attitude error plus IMU-to-trolley misalignment), with the
convention of Eq. 8: ``C_est = (I - [phi x]) C_true``. The equivalent gyro biases include the
Earth-rate projections of Eq. 6.

Beyond the paper, each channel accepts an optional random walk of the equivalent gyro bias (PSD
``gyro_bias_rw``), because the equivalent bias of Eq. 6 drifts when the heading changes (the
``psi_dot * phi_roll`` terms) and with the bias instability of the gyro; with it set to zero the
model is exactly the paper's. These models serve the engine, the budget and the Monte Carlo: they
exist here only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from trolley import units

VERTICAL_STATES = ("dr_D_m", "phi_pitch_eq_rad", "gyro_bias_y_eq_rad_s")
LEVEL_STATES = ("dr_N_m", "dr_E_m", "odo_scale_error", "phi_D_eq_rad", "gyro_bias_z_eq_rad_s")


@dataclass(frozen=True)
class ChannelNoise:
    """Continuous-time noise of the reduced-order models (Jiang 2017 Eq. 20, 25).

    Attributes
    ----------
    gyro_arw_rad_sqrt_s : equivalent angle random walk of the pitch and yaw axes (sigma_w), rad/sqrt(s).
    odo_scale_noise_per_sqrt_s : PSD root of the odometer scale-factor random walk (sigma_w_dk).
    gyro_bias_rw_rad_s_sqrt_s : PSD root of a random walk of the equivalent gyro bias (0 = paper).
    """

    gyro_arw_rad_sqrt_s: float
    odo_scale_noise_per_sqrt_s: float
    gyro_bias_rw_rad_s_sqrt_s: float = 0.0


@dataclass(frozen=True)
class InitialUncertainty:
    """1-sigma of the error states at the first fix (the diagonal of P(0), Jiang 2017 Eq. 32, 41).

    Attributes
    ----------
    position_m : horizontal and vertical position error (the first fix's sigma).
    pitch_rad : equivalent pitch (level) error.
    heading_rad : equivalent heading error.
    gyro_bias_y_rad_s, gyro_bias_z_rad_s : equivalent gyro biases of the pitch and yaw axes.
    odo_scale_error : odometer scale-factor error.
    """

    position_m: float
    pitch_rad: float
    heading_rad: float
    gyro_bias_y_rad_s: float
    gyro_bias_z_rad_s: float
    odo_scale_error: float


def vertical_matrices(speed_m_s):
    """Continuous-time A_v and G_v of the vertical channel (Jiang 2017 Eq. 19).

    Parameters
    ----------
    speed_m_s : float or array (...,)
        Odometer speed v_odo; may carry leading batch dimensions.

    Returns
    -------
    A : ndarray (..., 3, 3)
    G : ndarray (3, 2)
        Noise input for [w_pitch, w_bias_y]; the second column is the bias random walk (zero in
        the paper).
    """
    v = np.asarray(speed_m_s, dtype=float)
    A = np.zeros(v.shape + (3, 3))
    A[..., 0, 1] = v
    A[..., 1, 2] = -1.0
    G = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    return A, G


def level_matrices(velocity_north_m_s, velocity_east_m_s):
    """Continuous-time A_l and G_l of the level channel (Jiang 2017 Eq. 24).

    Parameters
    ----------
    velocity_north_m_s, velocity_east_m_s : float or array (...,)
        ``v cos(psi)`` and ``v sin(psi)``: the horizontal odometer velocity along north and east
        (passing components rather than ``v`` and ``psi`` keeps the interval averages exact).

    Returns
    -------
    A : ndarray (..., 5, 5)
    G : ndarray (5, 3)
        Noise input for [w_dk, w_D, w_bias_z].
    """
    vn = np.asarray(velocity_north_m_s, dtype=float)
    ve = np.asarray(velocity_east_m_s, dtype=float)
    A = np.zeros(np.broadcast_shapes(vn.shape, ve.shape) + (5, 5))
    A[..., 0, 2] = vn
    A[..., 0, 3] = ve
    A[..., 1, 2] = ve
    A[..., 1, 3] = -vn
    A[..., 3, 4] = -1.0
    G = np.zeros((5, 3))
    G[2, 0] = 1.0
    G[3, 1] = 1.0
    G[4, 2] = 1.0
    return A, G


def vertical_noise_psd(noise: ChannelNoise) -> np.ndarray:
    """Spectral density matrix of [w_pitch, w_bias_y] (Jiang 2017 Eq. 20)."""
    return np.diag([noise.gyro_arw_rad_sqrt_s**2, noise.gyro_bias_rw_rad_s_sqrt_s**2])


def level_noise_psd(noise: ChannelNoise) -> np.ndarray:
    """Spectral density matrix of [w_dk, w_D, w_bias_z] (Jiang 2017 Eq. 25)."""
    return np.diag([noise.odo_scale_noise_per_sqrt_s**2, noise.gyro_arw_rad_sqrt_s**2,
                    noise.gyro_bias_rw_rad_s_sqrt_s**2])


def vertical_initial_covariance(p0: InitialUncertainty) -> np.ndarray:
    """P_v(0) = diag(p_rD, p_phi_pitch, p_omega_y) (Jiang 2017 Eq. 32)."""
    return np.diag([p0.position_m**2, p0.pitch_rad**2, p0.gyro_bias_y_rad_s**2])


def level_initial_covariance(p0: InitialUncertainty) -> np.ndarray:
    """P_l(0) = diag(p_r, p_r, p_dk, p_phi_D, p_omega_z) (Jiang 2017 Eq. 41)."""
    return np.diag([p0.position_m**2, p0.position_m**2, p0.odo_scale_error**2,
                    p0.heading_rad**2, p0.gyro_bias_z_rad_s**2])


VERTICAL_H = np.array([[1.0, 0.0, 0.0]])  #: Jiang 2017 Eq. 21
LEVEL_H = np.array([[1.0, 0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0, 0.0]])  #: Jiang 2017 Eq. 24


def van_loan(A: np.ndarray, G: np.ndarray, Qc: np.ndarray, dt) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation of dx = A x dt + G dw, E[dw dw^T] = Qc dt, over steps dt (Van Loan 1978).

    Vectorised over leading batch dimensions of ``A`` and ``dt`` with scipy.linalg.expm.

    Parameters
    ----------
    A : ndarray (..., n, n)
    G : ndarray (n, m)
    Qc : ndarray (m, m)
    dt : float or ndarray (...,)

    Returns
    -------
    F : ndarray (..., n, n)
        Transition matrix exp(A dt).
    Qd : ndarray (..., n, n)
        Discrete process noise covariance, the integral of exp(A s) G Qc G^T exp(A s)^T ds.

    References
    ----------
    C. F. Van Loan, "Computing integrals involving the matrix exponential", IEEE TAC 23 (1978).
    """
    A = np.asarray(A, dtype=float)
    dt = np.asarray(dt, dtype=float)
    n = A.shape[-1]
    batch = np.broadcast_shapes(A.shape[:-2], dt.shape)
    A = np.broadcast_to(A, batch + (n, n))
    dtb = np.broadcast_to(dt, batch)[..., None, None]
    M = np.zeros(batch + (2 * n, 2 * n))
    M[..., :n, :n] = -A * dtb
    M[..., :n, n:] = (G @ Qc @ G.T) * dtb
    M[..., n:, n:] = np.swapaxes(A, -1, -2) * dtb
    E = _expm_nilpotent(M)
    if E is None:
        E = scipy.linalg.expm(M)
    F = np.swapaxes(E[..., n:, n:], -1, -2)
    Qd = F @ E[..., :n, n:]
    Qd = 0.5 * (Qd + np.swapaxes(Qd, -1, -2))
    return F, Qd


def _expm_nilpotent(M: np.ndarray) -> np.ndarray | None:
    """exp(M) as a finite series when M is nilpotent, else None.

    The reduced-order models of Jiang 2017 are nilpotent (A_v^3 = 0, A_l^3 = 0), and so is Van
    Loan's block-triangular matrix built from them; the series then ends and is exact. scipy's
    expm handles a batch one matrix at a time and was 90 % of a 10 km run; this is a few batched
    matrix products.
    """
    n = M.shape[-1]
    E = np.broadcast_to(np.eye(n), M.shape).copy()
    term = E.copy()
    for k in range(1, n + 1):
        term = term @ M / k
        if not np.any(term):
            return E
        E += term
    return None


def heading_error_from_gyrocompassing(gyro_bias_rad_s: float, latitude_rad: float) -> float:
    """Expected heading error of a static gyrocompassing alignment, phi_D = bias / (omega_ie cos L).

    Jiang 2017, Sec. 5 (text before Fig. 6).
    """
    return float(gyro_bias_rad_s / (units.EARTH_RATE_RAD_S * np.cos(latitude_rad)))


def equivalent_gyro_bias(gyro_bias_instability_rad_s, heading_error_rad, latitude_rad):
    """Equivalent gyro bias including the Earth-rate projection through the heading error.

    Jiang 2017 Eq. 6: the pitch-axis equivalent bias contains ``-omega_ieN * phi_D * cos(psi)``
    (and the yaw axis ``omega_ieN * phi_pitch * cos(psi)``, negligible since phi_pitch is small).
    Bounded over all headings, the equivalent bias is the instability plus
    ``omega_ie cos(L) |phi_D|`` (the text after Fig. 6: 0.1 deg/h and 0.6 deg give about
    0.25 deg/h).

    Parameters
    ----------
    gyro_bias_instability_rad_s : datasheet bias instability, rad/s.
    heading_error_rad : initial heading error, rad.
    latitude_rad : site latitude, rad.

    Returns
    -------
    Equivalent bias in rad/s.
    """
    return (np.abs(gyro_bias_instability_rad_s)
            + units.EARTH_RATE_RAD_S * np.cos(latitude_rad) * np.abs(heading_error_rad))


def levelled_roll_variance(t_s, stop_t_s, gyro_arw_rad_sqrt_s: float, gyro_bias_rw_rad_s_sqrt_s: float,
                           gyro_bias_rad_s: float) -> np.ndarray:
    """Variance of the gyro-integrated roll between stops at which the accelerometers level it.

    The roll is unobservable from the fixes (Jiang 2017 Sec. 4.1 drops it); the engine levels it
    at every stop and removes the roll error linearly in time between two levelled stops
    (``trolley.deadreckoning.with_roll_levelled``). What the linear removal leaves is a bridge
    of the integrated gyro noise: the constant part of the x-gyro bias is removed exactly, the
    angle random walk N leaves a Brownian bridge, ``N^2 T a (1 - a)`` at the fraction ``a`` of an
    interval of T seconds, and a random walk of the bias with PSD q (the bias instability as in
    :class:`ChannelNoise`) an integrated-Brownian bridge, ``q T^3 a^2 (1 - a)^2 / 3`` (the
    covariance of the integral of a Wiener process, ``q (s^2 t / 2 - s^3 / 6)`` for s <= t,
    interpolated linearly between its ends). Before the first and after the last levelled stop
    the roll is held and drifts freely: ``N^2 d + b^2 d^2 + q d^3 / 3`` at d seconds from it, b the
    whole bias sigma. The level error of the stops themselves (accelerometer bias, residual
    mounting) is common to all of them and is not included.

    Parameters
    ----------
    t_s : (K,) times at which the variance is wanted.
    stop_t_s : (S,) times of the levelled stops (at least one).
    gyro_arw_rad_sqrt_s : angle random walk of the x gyro, rad/sqrt(s).
    gyro_bias_rw_rad_s_sqrt_s : PSD root of the bias random walk, rad/s/sqrt(s).
    gyro_bias_rad_s : 1-sigma of the bias itself (what drifts the held roll beyond the ends).

    Returns
    -------
    (K,) variance of the roll, rad^2.
    """
    t = np.asarray(t_s, dtype=float)
    ts = np.unique(np.asarray(stop_t_s, dtype=float))
    if ts.size == 0:
        raise ValueError("levelled_roll_variance: no levelled stop")
    n2, q, b2 = gyro_arw_rad_sqrt_s ** 2, gyro_bias_rw_rad_s_sqrt_s ** 2, gyro_bias_rad_s ** 2
    j = np.clip(np.searchsorted(ts, t, side="right"), 1, max(ts.size - 1, 1))
    ta, tb = ts[j - 1], ts[np.minimum(j, ts.size - 1)]
    T = tb - ta
    a = np.divide(t - ta, T, out=np.zeros_like(t), where=T > 0)
    var = n2 * T * a * (1.0 - a) + q * T ** 3 * (a * (1.0 - a)) ** 2 / 3.0
    d = np.where(t < ts[0], ts[0] - t, np.where(t > ts[-1], t - ts[-1], 0.0))
    outside = d > 0
    var[outside] = (n2 * d + b2 * d ** 2 + q * d ** 3 / 3.0)[outside]
    return var


def observability_ranks(speed_m_s: float = 1.0, heading_rad: float = 0.3) -> tuple[int, int]:
    """Ranks of the observability matrices of the vertical and level channels (Jiang 2017 Eq. 26).

    Computed with python-control's ``obsv`` for uniform straight motion; 3 and 5 mean both
    channels are completely observable from position fixes.
    """
    return interval_observability_ranks([speed_m_s], [speed_m_s * np.cos(heading_rad)],
                                        [speed_m_s * np.sin(heading_rad)])


def interval_observability_ranks(speed_m_s, velocity_north_m_s, velocity_east_m_s) -> tuple[int, int]:
    """Smallest ranks of the observability matrices (Jiang 2017 Eq. 26) over a session's intervals.

    Each interval between two fixes has its own model (Eq. 19, 24) at that interval's mean
    odometer speed and mean north and east velocity; python-control's ``obsv`` gives the rank of
    each. 3 and 5 mean that every interval leaves both channels completely observable; a trolley
    that stands still (v = 0) observes the position only: ranks 1 and 2.

    Parameters
    ----------
    speed_m_s, velocity_north_m_s, velocity_east_m_s : (n,) interval means (n >= 1).

    Returns
    -------
    (vertical rank, level rank), the minimum over the intervals.
    """
    import control  # slow import (about 1.7 s): only when asked

    Av, _ = vertical_matrices(np.atleast_1d(np.asarray(speed_m_s, dtype=float)))
    Al, _ = level_matrices(np.atleast_1d(np.asarray(velocity_north_m_s, dtype=float)),
                           np.atleast_1d(np.asarray(velocity_east_m_s, dtype=float)))
    if Av.shape[0] == 0 or Av.shape[0] != Al.shape[0]:
        raise ValueError("give one speed and one north/east velocity per interval, at least one interval")
    rank_v = min(int(np.linalg.matrix_rank(control.obsv(A, VERTICAL_H))) for A in Av)
    rank_l = min(int(np.linalg.matrix_rank(control.obsv(A, LEVEL_H))) for A in Al)
    return rank_v, rank_l
