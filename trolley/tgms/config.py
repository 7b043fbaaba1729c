"""Configuration of a TGMS recording (the content of ``tgms.toml``, FORMATS.md section 3) as
dataclasses. Parsing the TOML text is done in ``survey.tgms_io``; this module only checks values.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trolley.tgms.camera import Camera, check_camera
from trolley.tgms.profiles import head_shape


#: plausible measuring-wheel diameters, m (a trolley's small wheel to a large rail wheel)
WHEEL_DIAMETER_RANGE_M = (0.02, 3.0)
#: farthest a camera centre may be from the IMU, m (both sit on one measuring frame)
CAMERA_DISTANCE_MAX_M = 10.0


@dataclass(frozen=True)
class TrackSettings:
    """[track] of tgms.toml.

    Attributes
    ----------
    rail_profile : "60E1" or "54E1".
    half_rail_spacing_m : L_r, track centre line to rail-profile frame origin (gauge point), m.
    rail_inclination : N of the 1:N rail inclination (0 = upright).
    alignment : file name of the LandXML design (relative to the recording folder).
    start_station_m : chainage at encoder count 0 (optional key; default: alignment start).
    """

    rail_profile: str = "60E1"
    half_rail_spacing_m: float = 0.7175
    rail_inclination: float = 40.0
    alignment: str = "alignment.xml"
    start_station_m: float | None = None


@dataclass(frozen=True)
class EncoderSettings:
    """[encoder] of tgms.toml: pulses per wheel revolution and nominal wheel diameter (m)."""

    pulses_per_rev: int = 1440
    wheel_diameter_m: float = 0.84

    @property
    def metres_per_count(self) -> float:
        return float(np.pi * self.wheel_diameter_m / self.pulses_per_rev)


@dataclass(frozen=True)
class TgmsConfig:
    """A whole tgms.toml.

    Attributes
    ----------
    track, encoder : settings.
    imu_rate_hz : [imu].rate_hz.
    cameras : {"left": Camera, "right": Camera}.
    """

    track: TrackSettings = field(default_factory=TrackSettings)
    encoder: EncoderSettings = field(default_factory=EncoderSettings)
    imu_rate_hz: float = 500.0
    cameras: dict[str, Camera] = field(default_factory=dict)

    def validate(self) -> None:
        """Raise ValueError naming the offending item if the configuration cannot be used."""
        head_shape(self.track.rail_profile)
        if not (0.3 < self.track.half_rail_spacing_m < 1.5):
            raise ValueError(f"track.half_rail_spacing_m = {self.track.half_rail_spacing_m} is not a plausible half rail spacing")
        if self.track.rail_inclination < 0:
            raise ValueError("track.rail_inclination must be >= 0")
        if self.encoder.pulses_per_rev <= 0 or self.encoder.wheel_diameter_m <= 0:
            raise ValueError("encoder.pulses_per_rev and encoder.wheel_diameter_m must be > 0")
        # metres, not millimetres (bug hunt 2026-11-27: 840.0 gave exit 0 and 894514 empty rows
        # running 90 km past a 400 m alignment)
        lo, hi = WHEEL_DIAMETER_RANGE_M
        if not lo <= self.encoder.wheel_diameter_m <= hi:
            raise ValueError(f"encoder.wheel_diameter_m = {self.encoder.wheel_diameter_m:g} is not a plausible measuring "
                             f"wheel diameter ({lo:g}-{hi:g} m): in metres?")
        if self.imu_rate_hz <= 0:
            raise ValueError("imu.rate_hz must be > 0")
        for side in ("left", "right"):
            if side not in self.cameras:
                raise ValueError(f"camera.{side} is missing")
            check_camera(self.cameras[side])
            d = float(np.linalg.norm(self.cameras[side].t_tgms_cam_m))
            if d > CAMERA_DISTANCE_MAX_M:
                # (bug hunt 2026-11-27: [-300, -547.5, 50] in mm ended in "no camera frame could be used")
                raise ValueError(f"camera.{side}.t_tgms_cam_m is {d:g} m from the IMU (at most "
                                 f"{CAMERA_DISTANCE_MAX_M:g} m on one measuring frame): in metres?")
