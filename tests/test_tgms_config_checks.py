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


@pytest.mark.parametrize("old, new, said", [
    ("distortion = ", "distorsion = ", "unknown key camera.left.distorsion (did you mean camera.left.distortion?)"),
    ("rail_inclination = ", "rail_inclinaton = ", "unknown key track.rail_inclinaton (did you mean track.rail_inclination?)"),
    ('format = "trolley-tgms/1"', 'format = "trolley-tgms/1"\nmodel = "x"', "unknown key model"),
], ids=["camera", "track", "top"])
def test_a_misspelt_key_is_refused_with_the_nearest_one(old, new, said):
    """(bug hunt 2026-11-27) A misspelt optional key fell back to its default without a word: no
    distortion, or rails taken as tilted 1:40 whatever the file meant."""
    text = _text()
    assert old in text
    with pytest.raises(TgmsFormatError) as e:
        parse_tgms_toml(text.replace(old, new, 1))
    assert str(e.value) == f"tgms.toml: {said}"


def test_a_stretch_that_both_cameras_lost_is_warned_about():
    """(bug hunt) Both laser files without frames 1200-1400 (18.7 m at 10 m/s) left 76 empty cells
    and no warning; one camera's loss was warned about."""
    from types import SimpleNamespace

    import numpy as np

    from survey.tgms_io import process_warnings
    from trolley.tgms.irregularities import Irregularities
    from trolley.tgms.recording import LaserPoints

    n = 2000
    frame = np.arange(n)
    t = frame / 100.0
    s = 10.0 + 10.0 * t
    seen = (frame < 1200) | (frame > 1400)
    lp = LaserPoints(frame=frame[seen], t_s=t[seen], u_px=np.zeros(seen.sum()), v_px=np.zeros(seen.sum()))
    rec = SimpleNamespace(lasers={"left": lp, "right": lp},
                          config=SimpleNamespace(track=SimpleNamespace(rail_inclination=40.0, rail_profile="60E1")))
    fit = SimpleNamespace(angle_rad=np.zeros(n))
    g = np.arange(10.0, 210.0, 0.25)
    v = np.where((g > s[1199]) & (g < s[1401]), np.nan, 0.0)
    grid = Irregularities(g, *([v] * 8))
    res = SimpleNamespace(vision=SimpleNamespace(frame=frame, t_s=np.where(seen, t, np.nan), ok=seen, left=fit, right=fit),
                          odometry=SimpleNamespace(scale_error=1e-3, sigma_scale_error=2e-4),
                          frames=SimpleNamespace(s_m=np.where(seen, s, np.nan)), grid=grid)
    w = process_warnings(rec, res, 0.25)
    assert len(w) == 1 and w[0].startswith("laser_left.csv and laser_right.csv both have no rows for frames "
                                           "1200-1400 (t_s 11.99-14.01 s, s 129.9-150.1 m)"), w
    assert f"those {int(np.isnan(v).sum())} cells" in w[0]


def _mismatch_case(k, half_angle, inclination=40.0, profile="60E1"):
    from types import SimpleNamespace

    import numpy as np

    from survey.tgms_io import _configuration_mismatch

    n = 200
    noise = np.random.default_rng(0).normal(0, 1e-3, n)
    rec = SimpleNamespace(config=SimpleNamespace(track=SimpleNamespace(rail_inclination=inclination,
                                                                       rail_profile=profile)))
    res = SimpleNamespace(odometry=SimpleNamespace(scale_error=k, sigma_scale_error=9e-4),
                          vision=SimpleNamespace(left=SimpleNamespace(angle_rad=-half_angle + noise),
                                                 right=SimpleNamespace(angle_rad=half_angle + noise)))
    return _configuration_mismatch(rec, res)


def test_an_implausible_encoder_scale_or_rail_tilt_is_warned_about():
    """(bug hunt) start_station_m 5 m off (k = -3.1 %: 1.4 mm of cross-level error) and
    rail_inclination = 0 for 1:40 rails (0.88 mm of gauge bias) gave exit 0 and no word."""
    assert _mismatch_case(1.4e-3, 1e-4) == []
    w = _mismatch_case(-3.06e-2, 1e-4)
    assert len(w) == 1 and w[0].startswith("the odometry fitted an encoder scale error of -3.06 % (+-0.09 %)")
    assert "track.start_station_m" in w[0]
    w = _mismatch_case(1.4e-3, -0.025, inclination=0.0)
    assert len(w) == 1 and "lean 25 mrad more towards the track centre" in w[0] and "as if 1:40" in w[0], w
    assert _mismatch_case(float("nan"), 0.0) == []
