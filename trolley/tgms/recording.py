"""A TGMS recording held in memory: what the recording folder of FORMATS.md section 3 contains
(configuration, design alignment, IMU, encoder and the laser points of both cameras)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trolley.alignment import Alignment
from trolley.tgms.config import TgmsConfig


@dataclass
class LaserPoints:
    """Laser-line points of one camera (rows of laser_left.csv / laser_right.csv)."""

    frame: np.ndarray
    t_s: np.ndarray
    u_px: np.ndarray
    v_px: np.ndarray


@dataclass
class Recording:
    """A TGMS recording in memory (what the folder of FORMATS.md section 3 holds).

    Attributes
    ----------
    config : TgmsConfig.
    alignment : design geometry.
    imu_t_s, imu_w_rad_s (n, 3), imu_f_m_s2 (n, 3) : IMU samples.
    enc_t_s, enc_count : encoder samples.
    lasers : {"left": LaserPoints, "right": LaserPoints}.
    """

    config: TgmsConfig
    alignment: Alignment
    imu_t_s: np.ndarray
    imu_w_rad_s: np.ndarray
    imu_f_m_s2: np.ndarray
    enc_t_s: np.ndarray
    enc_count: np.ndarray
    lasers: dict[str, LaserPoints] = field(default_factory=dict)
