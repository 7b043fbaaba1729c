"""Unit conversions between the SI used inside the code and the units people use at the edges.

Everything inside ``trolley`` is SI (m, s, rad, rad/s, rad/sqrt(s), m/s^2). Degrees, deg/h,
deg/sqrt(h), mm and micro-g appear only in files, on the command line and in sheets, and are
converted here and nowhere else.
"""
from __future__ import annotations

import numpy as np

#: Earth rotation rate (WGS-84), rad/s.
EARTH_RATE_RAD_S = 7.292115e-5
#: Standard gravity, m/s^2 (used only to convert micro-g figures).
STANDARD_GRAVITY_M_S2 = 9.80665

_DEG = np.pi / 180.0
_HOUR_S = 3600.0


def deg_to_rad(x):
    """Degrees to radians."""
    return np.asarray(x, dtype=float) * _DEG if np.ndim(x) else float(x) * _DEG


def rad_to_deg(x):
    """Radians to degrees."""
    return np.asarray(x, dtype=float) / _DEG if np.ndim(x) else float(x) / _DEG


def deg_h_to_rad_s(x):
    """Gyro bias: deg/h to rad/s."""
    return deg_to_rad(x) / _HOUR_S


def rad_s_to_deg_h(x):
    """Gyro bias: rad/s to deg/h."""
    return rad_to_deg(x) * _HOUR_S


def deg_sqrt_h_to_rad_sqrt_s(x):
    """Angle random walk: deg/sqrt(h) to rad/sqrt(s)."""
    return deg_to_rad(x) / np.sqrt(_HOUR_S)


def rad_sqrt_s_to_deg_sqrt_h(x):
    """Angle random walk: rad/sqrt(s) to deg/sqrt(h)."""
    return rad_to_deg(x) * np.sqrt(_HOUR_S)


def mm_to_m(x):
    """Millimetres to metres."""
    return np.asarray(x, dtype=float) * 1e-3 if np.ndim(x) else float(x) * 1e-3


def m_to_mm(x):
    """Metres to millimetres."""
    return np.asarray(x, dtype=float) * 1e3 if np.ndim(x) else float(x) * 1e3


def ug_to_m_s2(x):
    """Accelerometer bias: micro-g to m/s^2."""
    return np.asarray(x, dtype=float) * 1e-6 * STANDARD_GRAVITY_M_S2 if np.ndim(x) else float(x) * 1e-6 * STANDARD_GRAVITY_M_S2


def m_s2_to_ug(x):
    """Accelerometer bias: m/s^2 to micro-g."""
    return np.asarray(x, dtype=float) / (1e-6 * STANDARD_GRAVITY_M_S2) if np.ndim(x) else float(x) / (1e-6 * STANDARD_GRAVITY_M_S2)


def arcsec_to_rad(x):
    """Arc seconds to radians."""
    return deg_to_rad(x) / 3600.0


def gon_to_rad(x):
    """Gon (grads) to radians."""
    return np.asarray(x, dtype=float) * (np.pi / 200.0) if np.ndim(x) else float(x) * (np.pi / 200.0)


def ratio_to_mm_per_m(x):
    """Dimensionless rate (m/m, e.g. twist or gauge change rate) to mm/m (per mille)."""
    return np.asarray(x, dtype=float) * 1e3 if np.ndim(x) else float(x) * 1e3


def mm_per_m_to_ratio(x):
    """Rate in mm/m (per mille) to a dimensionless ratio (m/m)."""
    return np.asarray(x, dtype=float) * 1e-3 if np.ndim(x) else float(x) * 1e-3


#: US survey foot, m (1200/3937 exactly; the foot of the US State Plane grids in feet).
US_SURVEY_FOOT_M = 1200.0 / 3937.0
#: International foot, m (0.3048 exactly).
INTERNATIONAL_FOOT_M = 0.3048
#: International inch, m (the unit of LandXML cant values in imperial files).
INCH_M = 0.0254
#: International mile, m.
INTERNATIONAL_MILE_M = 1609.344
