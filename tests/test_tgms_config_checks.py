"""tgms.toml values that cannot be right (units in mm, a fractional pulse count) are refused
naming the key, before any CSV is read."""
from __future__ import annotations

import pytest

from survey.tgms_io import TgmsFormatError, parse_tgms_toml, tgms_toml_text
from trolley.tgms.config import TgmsConfig
from trolley.tgms.simulate import default_cameras


def _text() -> str:
    return tgms_toml_text(TgmsConfig(cameras=default_cameras()))


def test_the_default_configuration_reads_back():
    parse_tgms_toml(_text())


@pytest.mark.parametrize("old, new, said", [
    ("pulses_per_rev = 1440", "pulses_per_rev = 1440.7", "encoder.pulses_per_rev must be a whole number"),
    ("wheel_diameter_m = 0.84", "wheel_diameter_m = 840.0", "encoder.wheel_diameter_m = 840 is not a plausible"),
    ("t_tgms_cam_m = [-0.3, -0.5475,", "t_tgms_cam_m = [-300.0, -547.5,", "camera.left.t_tgms_cam_m is"),
], ids=["fractional-pulses", "wheel-in-mm", "camera-in-mm"])
def test_values_in_the_wrong_unit_are_refused_naming_the_key(old, new, said):
    text = _text()
    assert old in text
    with pytest.raises(TgmsFormatError, match=f"^tgms.toml: {said}"):
        parse_tgms_toml(text.replace(old, new, 1))
