"""Raw session folder (FORMATS.md sec. 1): write -> read round trip, atomic writing, design."""
from __future__ import annotations

import math
import os
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from survey.sessionio import (SessionFormatError, read_design, read_session, read_truth_csv,
                              session_toml_text, write_session, write_truth_csv)
from trolley import units
from trolley.sensors import IMU_PRESETS, OdometerFigures
from trolley.session import Fixes, RawSession, SessionMeta, TrolleyGeometry

REPO = Path(__file__).resolve().parents[1]


def tiny_session(n: int = 50, seed: int = 0) -> RawSession:
    rng = np.random.default_rng(seed)
    meta = SessionMeta(
        latitude_rad=float(units.deg_to_rad(28.0)), height_m=50.0,
        trolley=TrolleyGeometry(prism_lever_arm_m=np.array([0.01, -0.02, -0.6]),
                                imu_misalignment_rad=np.array([1e-3, -2e-3, 3e-3]),
                                rail_spacing_m=1.5, nominal_gauge_m=1.435),
        imu=IMU_PRESETS["fog"], odometer=OdometerFigures(8e-6, 1e-4, 1e-4),
        fix_sigma_m=0.0006, static_s=30.0, initial_heading_rad=float("nan"))
    t = np.arange(1, n + 1) / 200.0
    w = rng.normal(0, 2e-5, (n, 3)) + 7e-5
    f = rng.normal(0, 1e-3, (n, 3)) + np.array([0.0, 0.0, -9.79])
    odo_t = np.arange(0, n // 2 + 1) / 100.0
    odo = np.round(np.cumsum(rng.uniform(0, 0.01, odo_t.size)), 4)
    fixes = Fixes(t_s=np.array([0.05, 0.1, 0.2]), point=np.array(["CP0000", "NA", "x,y"], dtype=object),
                  enh_m=np.array([[500123.45678, 3100234.56789, 50.12345],
                                  [500183.1, 3100264.2, 50.6],
                                  [500243.0, 3100294.0, 51.1]]),
                  sigma_m=np.array([[6e-4, 6e-4, 6e-4], [1e-3, 1e-3, 2e-3], [6e-4, 6e-4, 6e-4]]))
    return RawSession(meta=meta, imu_t_s=t, imu_w_rad_s=w, imu_f_m_s2=f, odo_t_s=odo_t,
                      odo_distance_m=odo, fixes=fixes, gauge_t_s=np.array([0.1, 0.2]),
                      gauge_m=np.array([1.4351, 1.4349]))


def assert_meta_equal(a: SessionMeta, b: SessionMeta) -> None:
    assert a.latitude_rad == pytest.approx(b.latitude_rad, rel=1e-15)
    assert a.height_m == b.height_m
    np.testing.assert_array_equal(a.trolley.prism_lever_arm_m, b.trolley.prism_lever_arm_m)
    np.testing.assert_array_equal(a.trolley.imu_misalignment_rad, b.trolley.imu_misalignment_rad)
    assert a.trolley.rail_spacing_m == b.trolley.rail_spacing_m
    assert a.trolley.nominal_gauge_m == b.trolley.nominal_gauge_m
    for field in ("gyro_bias_instability_rad_s", "gyro_arw_rad_sqrt_s", "accel_bias_m_s2",
                  "accel_vrw_m_s_sqrt_s", "gyro_scale_factor"):
        assert getattr(a.imu, field) == pytest.approx(getattr(b.imu, field), rel=1e-14)
    assert (a.imu.name, a.imu.gyrocompassing) == (b.imu.name, b.imu.gyrocompassing)
    assert a.odometer == b.odometer
    assert a.fix_sigma_m == b.fix_sigma_m and a.static_s == b.static_s
    assert (math.isnan(a.initial_heading_rad) and math.isnan(b.initial_heading_rad)) or \
        a.initial_heading_rad == pytest.approx(b.initial_heading_rad, rel=1e-15)
    assert a.design_alignment == b.design_alignment


@pytest.mark.parametrize("exact", [False, True])
def test_round_trip(tmp_path, exact):
    s = tiny_session()
    write_session(tmp_path / "s", s, exact=exact)
    r = read_session(tmp_path / "s")
    assert_meta_equal(r.meta, s.meta)
    # times, odometer, fixes, gauge: bit for bit
    for a, b in [(r.imu_t_s, s.imu_t_s), (r.odo_t_s, s.odo_t_s),
                 (r.odo_distance_m, s.odo_distance_m), (r.fixes.t_s, s.fixes.t_s),
                 (r.fixes.enh_m, s.fixes.enh_m), (r.fixes.sigma_m, s.fixes.sigma_m),
                 (r.gauge_t_s, s.gauge_t_s), (r.gauge_m, s.gauge_m)]:
        np.testing.assert_array_equal(a, b)
    assert list(r.fixes.point) == list(s.fixes.point)
    if exact:
        np.testing.assert_array_equal(r.imu_w_rad_s, s.imu_w_rad_s)
        np.testing.assert_array_equal(r.imu_f_m_s2, s.imu_f_m_s2)
    else:  # 12 significant digits
        np.testing.assert_allclose(r.imu_w_rad_s, s.imu_w_rad_s, rtol=1e-11, atol=0)
        np.testing.assert_allclose(r.imu_f_m_s2, s.imu_f_m_s2, rtol=1e-11, atol=0)
        assert not np.array_equal(r.imu_w_rad_s, s.imu_w_rad_s)   # the rounding is real
    # raw data handed out cannot be changed by accident downstream
    for a in (r.imu_t_s, r.imu_w_rad_s, r.imu_f_m_s2, r.odo_t_s, r.odo_distance_m, r.gauge_m):
        with pytest.raises(ValueError, match="read-only"):
            a[0] = 1.0
    # a second write of what was read gives the same files
    write_session(tmp_path / "s2", read_session(tmp_path / "s"), exact=exact)
    for name in ("session.toml", "imu.csv", "odometer.csv", "fixes.csv", "gauge.csv"):
        assert (tmp_path / "s" / name).read_bytes() == (tmp_path / "s2" / name).read_bytes()


def test_session_toml_has_every_formats_key():
    data = tomllib.loads(session_toml_text(replace(tiny_session().meta,
                                                   design_alignment="alignment.xml")))
    expected = {
        "format": None,
        "site": {"latitude_deg", "height_m"},
        "trolley": {"prism_lever_arm_m", "imu_misalignment_rad", "rail_spacing_m",
                    "nominal_gauge_m"},
        "imu": {"gyro_bias_instability_deg_h", "gyro_arw_deg_sqrt_h", "accel_bias_ug"},
        "odometer": {"scale_noise_per_sqrt_s"},
        "totalstation": {"sigma_m"},
        "alignment": {"static_s", "initial_heading_deg"},
        "design": {"alignment"},
    }
    assert data["format"] == "trolley-raw-session/1"
    for table, keys in expected.items():
        if keys:
            assert keys <= set(data[table]), table
    assert data["imu"]["gyro_bias_instability_deg_h"] == 0.1      # written in datasheet units
    assert data["site"]["latitude_deg"] == 28.0
    assert math.isnan(data["alignment"]["initial_heading_deg"])


def test_minimal_toml_gets_documented_defaults(tmp_path):
    s = tiny_session()
    write_session(tmp_path / "s", s)
    (tmp_path / "s" / "session.toml").write_text(
        'format = "trolley-raw-session/1"\n[site]\nlatitude_deg = 28\n', encoding="utf-8")
    m = read_session(tmp_path / "s").meta
    assert m.latitude_rad == pytest.approx(np.radians(28.0))
    assert m.height_m == 0.0 and m.imu is None and m.static_s == 900.0
    assert m.fix_sigma_m == 0.0006 and math.isnan(m.initial_heading_rad)
    assert m.odometer == OdometerFigures() and m.design_alignment is None
    np.testing.assert_array_equal(m.trolley.prism_lever_arm_m, [0.0, 0.0, -0.6])
    # fixes without sigma columns take [totalstation].sigma_m
    (tmp_path / "s" / "fixes.csv").write_text("t_s,point,E_m,N_m,H_m,comment\n"
                                              "1.0,CP1,1.0,2.0,3.0,hello\n", encoding="utf-8")
    fx = read_session(tmp_path / "s").fixes
    np.testing.assert_array_equal(fx.sigma_m, [[0.0006] * 3])


def test_unknown_columns_ignored_and_blank_tolerant_header(tmp_path):
    write_session(tmp_path / "s", tiny_session())
    p = tmp_path / "s" / "odometer.csv"
    rows = p.read_text().splitlines()
    p.write_text("\n".join([" t_s , distance_m ,note"] + [r + ",x" for r in rows[1:]]) + "\n")
    r = read_session(tmp_path / "s")
    np.testing.assert_array_equal(r.odo_distance_m, tiny_session().odo_distance_m)


def test_design_copied_and_parsed(tmp_path):
    xml = (REPO / "projects" / "demo" / "alignment.xml").read_text(encoding="utf-8")
    write_session(tmp_path / "s", tiny_session(), design_xml=xml)
    assert (tmp_path / "s" / "alignment.xml").read_text(encoding="utf-8") == xml
    meta = read_session(tmp_path / "s").meta
    assert meta.design_alignment == "alignment.xml"
    a = read_design(tmp_path / "s", meta)
    assert a.end_chainage_m > a.start_chainage_m
    (tmp_path / "s" / "alignment.xml").unlink()
    with pytest.raises(SessionFormatError, match="design.alignment"):
        read_design(tmp_path / "s", meta)


def test_write_is_atomic(tmp_path):
    s = tiny_session()
    target = tmp_path / "s"
    write_session(target, s)
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(FileExistsError):
        write_session(target, s)
    bad = replace(s, imu_w_rad_s=s.imu_w_rad_s.copy())
    bad.imu_w_rad_s[7, 1] = np.nan
    with pytest.raises(ValueError, match="imu.csv"):
        write_session(tmp_path / "new", bad)
    with pytest.raises(ValueError, match="imu.csv"):
        write_session(target, bad, overwrite=True)
    # nothing partial left behind; the old folder is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    np.testing.assert_array_equal(read_session(target).odo_distance_m, s.odo_distance_m)
    # a writer that dies half-way leaves nothing either

    def boom(path):
        path.write_text("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        write_session(tmp_path / "other", s, extra_files={"truth.csv": boom})
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    # overwrite replaces the folder
    s2 = tiny_session(seed=1)
    write_session(target, s2, overwrite=True)
    np.testing.assert_array_equal(read_session(target).imu_t_s, s2.imu_t_s)
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert oct(os.stat(target).st_mode & 0o777) == "0o755"


def test_truth_csv_round_trip(tmp_path):
    from trolley.landxml import parse_landxml
    from trolley.truthsim import SimulationConfig, simulate_survey

    a = parse_landxml((REPO / "projects" / "demo" / "alignment.xml").read_text(encoding="utf-8"))
    sim = simulate_survey(a, SimulationConfig(length_m=60.0, static_s=2.0, stop_s=1.0,
                                              imu_rate_hz=50.0))
    write_truth_csv(tmp_path / "truth.csv", sim.truth, step_m=0.1)
    back = read_truth_csv(tmp_path / "truth.csv")
    ref = sim.truth.resampled(0.1)
    assert back.chainage_m.size == 601
    np.testing.assert_array_equal(back.chainage_m, ref.chainage_m)
    for name in ("E_m", "N_m", "H_m", "roll_rad", "pitch_rad", "yaw_rad", "gauge_m"):
        np.testing.assert_array_equal(getattr(back, name), getattr(ref, name))
    for name in ("cant_m", "lateral_m", "vertical_m"):   # written in mm
        np.testing.assert_allclose(getattr(back, name), getattr(ref, name), rtol=1e-15, atol=1e-18)
    # the truth at the IMU times agrees with the chainage-domain truth
    i = sim.truth.t_s.size // 2
    at = sim.truth.at_chainage(sim.truth.chainage_m[i])
    assert at.E_m == pytest.approx(sim.truth.E_m[i], abs=1e-9)
    assert at.yaw_rad == pytest.approx(sim.truth.yaw_rad[i], abs=1e-12)


def test_empty_gauge_and_missing_gauge(tmp_path):
    s = replace(tiny_session(), gauge_t_s=None, gauge_m=None)
    write_session(tmp_path / "s", s)
    assert not (tmp_path / "s" / "gauge.csv").exists()
    assert read_session(tmp_path / "s").gauge_m is None


def test_exact_mode_is_bit_exact_for_any_double(tmp_path):
    """repr-written doubles of every magnitude and sign that a sensor can give (down to 1e-300;
    larger than sessionio.PLAUSIBLE_ABS is refused) read back bit for bit (pandas C parser)."""
    rng = np.random.default_rng(5)
    n = 20000
    s = tiny_session(n)
    mag = 10.0 ** rng.uniform(-300, 0.9, (n, 3))
    w = rng.choice([-1.0, 1.0], (n, 3)) * mag * rng.uniform(1, 10, (n, 3))
    f = rng.normal(0, 1, (n, 3)) * 10.0 ** rng.integers(-17, 2, (n, 3))
    t = np.cumsum(rng.uniform(0, 1e-3, n)) + 1e6 * rng.uniform()
    # the other files in the IMU's time span (the reader refuses files that are not one survey)
    s = replace(s, imu_t_s=t, imu_w_rad_s=w, imu_f_m_s2=f, odo_t_s=np.linspace(t[0], t[-1], s.odo_t_s.size),
                fixes=replace(s.fixes, t_s=t[[10, 100, 1000]]), gauge_t_s=t[[50, 60]])
    write_session(tmp_path / "s", s, exact=True)
    r = read_session(tmp_path / "s")
    np.testing.assert_array_equal(r.imu_t_s, t)
    np.testing.assert_array_equal(r.imu_w_rad_s, w)
    np.testing.assert_array_equal(r.imu_f_m_s2, f)


def test_fix_covariances_round_trip_and_a_non_covariance_is_refused(tmp_path):
    # the optional cov_EN_m2, cov_EH_m2, cov_NH_m2 columns of fixes.csv: written when the fixes have
    # them, read bit for bit; a file without them reads as uncorrelated; three correlations that
    # are no covariance (each within +-1, together not positive semi-definite) name the row
    from dataclasses import replace

    from survey.sessionio import SessionFormatError
    s = tiny_session()
    n = len(s.fixes)
    sig = np.asarray(s.fixes.sigma_m)
    cov = np.column_stack([0.6 * sig[:, 0] * sig[:, 1], -0.1 * sig[:, 0] * sig[:, 2], 0.05 * sig[:, 1] * sig[:, 2]])
    write_session(tmp_path / "s", replace(s, fixes=replace(s.fixes, cov_m2=cov)), exact=True)
    r = read_session(tmp_path / "s")
    np.testing.assert_array_equal(r.fixes.cov_m2, cov)
    c = r.fixes.covariance_enh_m2()
    assert c.shape == (n, 3, 3) and c[0, 1, 0] == cov[0, 0] and c[0, 2, 2] == sig[0, 2] ** 2
    assert read_session_without_cov(tmp_path, s).fixes.cov_m2 is None
    bad = cov.copy()
    bad[-1] = [0.9 * sig[-1, 0] * sig[-1, 1], 0.9 * sig[-1, 0] * sig[-1, 2], -0.9 * sig[-1, 1] * sig[-1, 2]]
    write_session(tmp_path / "b", replace(s, fixes=replace(s.fixes, cov_m2=bad)), exact=True)
    with pytest.raises(SessionFormatError, match=rf"fixes.csv: row {n + 1}, column cov_\w\w_m2: .*no covariance"):
        read_session(tmp_path / "b")


def read_session_without_cov(tmp_path, s):
    write_session(tmp_path / "plain", s, exact=True)
    return read_session(tmp_path / "plain")
