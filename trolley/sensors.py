"""Datasheet figures of the trolley's sensors and the IMU grade presets.

One place for these figures: the simulator draws its errors from them, the engine builds the
filters' initial covariance and noise from them, and the budget evaluates them. All values SI.

Presets follow Jiang 2017 Sec. 2 (navigation-grade RLG: 0.03 deg/h, 0.005 deg/sqrt(h), 50 ug
quartz accelerometers) and Sec. 5 (typical FOG: 0.1 deg/h, 0.007 deg/sqrt(h)); the MEMS unit is a
good industrial MEMS IMU (figures marked as example in ``docs/glossary.md``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trolley import units


@dataclass(frozen=True)
class ImuFigures:
    """Datasheet figures of one IMU (SI units).

    Attributes
    ----------
    gyro_bias_instability_rad_s : gyro bias instability (the datasheet "in-run" figure), rad/s.
    gyro_arw_rad_sqrt_s : gyro angle random walk, rad/sqrt(s).
    accel_bias_m_s2 : accelerometer bias, m/s^2.
    accel_vrw_m_s_sqrt_s : accelerometer velocity random walk (white noise), m/s/sqrt(s).
    gyro_scale_factor : gyro scale-factor error (dimensionless, e.g. 1e-5 = 10 ppm).
    name : short name of the grade.
    gyrocompassing : whether the gyros are good enough to find north in the static alignment.
    """

    gyro_bias_instability_rad_s: float
    gyro_arw_rad_sqrt_s: float
    accel_bias_m_s2: float
    accel_vrw_m_s_sqrt_s: float = 0.0
    gyro_scale_factor: float = 0.0
    name: str = "custom"
    gyrocompassing: bool = True

    @property
    def gyro_turn_on_bias_rad_s(self) -> float:
        """1-sigma of a gyro's bias at switch-on (its turn-on repeatability), rad/s. The presets
        and session files give one figure, the in-run bias instability, and it stands for this
        too: the truth simulator draws the turn-on bias with it."""
        return self.gyro_bias_instability_rad_s

    @property
    def gyro_bias_sigma_rad_s(self) -> float:
        """1-sigma of a gyro's bias at any moment (the static alignment's, which gyrocompassing
        reads as a heading error): turn-on and in-run parts in quadrature, sqrt(2) x the bias
        instability. The in-run part alone made the heading sigma 1.22 x too small over 64
        simulated RLG surveys, and correct fixes were rejected after the alignment."""
        return float(np.hypot(self.gyro_turn_on_bias_rad_s, self.gyro_bias_instability_rad_s))


@dataclass(frozen=True)
class OdometerFigures:
    """Odometer figures (Jiang 2017 Eq. 11).

    Attributes
    ----------
    scale_noise_per_sqrt_s : PSD root of the scale-factor random walk w_dk, 1/sqrt(s).
    scale_error : 1-sigma of the scale-factor error left after calibration (dimensionless).
    resolution_m : distance of one encoder count (quantisation).
    """

    scale_noise_per_sqrt_s: float = 8e-6
    scale_error: float = 1e-4
    resolution_m: float = 1e-4


def _imu(name: str, bi_deg_h: float, arw_deg_sqrt_h: float, accel_bias_ug: float,
         vrw_ug_sqrt_hz: float, scale_ppm: float, gyrocompassing: bool) -> ImuFigures:
    return ImuFigures(
        gyro_bias_instability_rad_s=units.deg_h_to_rad_s(bi_deg_h),
        gyro_arw_rad_sqrt_s=units.deg_sqrt_h_to_rad_sqrt_s(arw_deg_sqrt_h),
        accel_bias_m_s2=units.ug_to_m_s2(accel_bias_ug),
        # ug/sqrt(Hz) of white acceleration noise is the same number as ug * sqrt(s) of velocity random walk
        accel_vrw_m_s_sqrt_s=units.ug_to_m_s2(vrw_ug_sqrt_hz),
        gyro_scale_factor=scale_ppm * 1e-6,
        name=name,
        gyrocompassing=gyrocompassing,
    )


#: IMU grades: navigation RLG and tactical FOG of Jiang 2017, and an industrial MEMS (example).
IMU_PRESETS: dict[str, ImuFigures] = {
    "rlg": _imu("rlg", 0.03, 0.005, 50.0, 10.0, 5.0, True),
    "fog": _imu("fog", 0.1, 0.007, 100.0, 20.0, 20.0, True),
    "mems": _imu("mems", 3.0, 0.15, 500.0, 60.0, 300.0, False),
}
