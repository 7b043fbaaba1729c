"""Earth model for the strapdown equations: normal gravity, Earth rate and transport rate.

All in the local-level NED navigation frame of Jiang 2017 Sec. 3.1 (Eq. 1-2: omega_in^n =
omega_ie^n + omega_en^n). WGS-84 constants; the transport rate uses one radius R + h for both
meridian and prime-vertical curvature (good to 0.7 % of a rate that is itself ~1e-7 rad/s for a
trolley at walking speed).

References
----------
Jiang, Q., Wu, W., Jiang, M., Li, Y. (2017). A new filtering and smoothing algorithm for railway
track surveying based on landmark and IMU/odometer. Sensors 17(6), 1438. Sec. 3.1, Eq. 1-2.
Moritz, H. (2000). Geodetic Reference System 1980. J. Geodesy 74, 128-133 (Somigliana's normal
gravity and its free-air height correction).
"""
from __future__ import annotations

import numpy as np

from trolley.units import EARTH_RATE_RAD_S

#: WGS-84 semi-major axis, m.
EARTH_RADIUS_M = 6378137.0
#: Highest |latitude| the survey models take, deg: north-seeking alignment (gyrocompassing) and the
#: local-level frame's heading break down at the poles (no railway runs north of 71 deg)
MAX_LATITUDE_DEG = 85.0
_FLATTENING = 1.0 / 298.257223563
_GAMMA_EQUATOR = 9.7803253359
_SOMIGLIANA_K = 0.00193185265241
_ECC2 = 0.00669437999013
_M_RATIO = 0.00344978650684  # omega^2 a^2 b / GM


def normal_gravity_m_s2(latitude_rad, height_m=0.0):
    """Magnitude of normal gravity (Somigliana, with the second-order free-air correction).

    Parameters
    ----------
    latitude_rad : array_like, geodetic latitude, rad.
    height_m : array_like, ellipsoidal height, m.

    Returns
    -------
    ndarray or float
        Normal gravity, m/s^2 (points down along the plumb line: g^n = [0, 0, g]).
    """
    s2 = np.sin(latitude_rad) ** 2
    g0 = _GAMMA_EQUATOR * (1.0 + _SOMIGLIANA_K * s2) / np.sqrt(1.0 - _ECC2 * s2)
    h = np.asarray(height_m, dtype=float)
    a = EARTH_RADIUS_M
    return g0 * (1.0 - 2.0 / a * (1.0 + _FLATTENING + _M_RATIO - 2.0 * _FLATTENING * s2) * h
                 + 3.0 * h * h / (a * a))


def earth_rate_n(latitude_rad) -> np.ndarray:
    """Earth rotation rate in NED, omega_ie^n = W [cos L, 0, -sin L] (Jiang 2017 Eq. 2).

    Parameters
    ----------
    latitude_rad : array_like (shape S), rad.

    Returns
    -------
    ndarray (S + (3,)), rad/s.
    """
    L = np.asarray(latitude_rad, dtype=float)
    return np.stack([EARTH_RATE_RAD_S * np.cos(L), np.zeros(L.shape),
                     -EARTH_RATE_RAD_S * np.sin(L)], axis=-1)


def transport_rate_n(v_n_m_s, latitude_rad, height_m=0.0) -> np.ndarray:
    """Turn rate of the NED frame over the Earth, omega_en^n.

    omega_en^n = [v_E / (R + h), -v_N / (R + h), -v_E tan L / (R + h)].

    Parameters
    ----------
    v_n_m_s : array_like (..., 3), velocity over the ground in NED, m/s.
    latitude_rad, height_m : array_like broadcastable to ``v_n_m_s[..., 0]``.

    Returns
    -------
    ndarray (..., 3), rad/s.
    """
    v = np.asarray(v_n_m_s, dtype=float)
    r = EARTH_RADIUS_M + np.asarray(height_m, dtype=float)
    vN, vE = v[..., 0], v[..., 1]
    return np.stack([vE / r, -vN / r, -vE * np.tan(latitude_rad) / r], axis=-1)
