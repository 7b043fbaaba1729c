"""The engine in a projected grid: a site 200 km off the UTM central meridian (0.96 deg of grid
convergence) processes as accurately as one on it once the CRS is given, and is refused, naming
the convergence, when it is not."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from survey.cli import app
from survey.sessionio import SessionFormatError, read_session, session_toml_text, write_session
from trolley.engine import GridRotationError, fix_rotation, process_session
from trolley.landxml import landxml_text, parse_landxml
from trolley.sensors import IMU_PRESETS
from trolley.truthsim import SimulationConfig, simulate_survey
from trolley.validation import track_errors

DEMO = Path(__file__).resolve().parents[1] / "projects" / "demo" / "alignment.xml"
CRS = "EPSG:32650"  # UTM 50N: the demo design lies on its central meridian (E 500 km, 28 deg N)
SHORT = dict(length_m=360.0, static_s=300.0, imu_rate_hz=100.0, imu=IMU_PRESETS["rlg"], crs=CRS)
OFF_M = 200000.0
runner = CliRunner()


@pytest.fixture(scope="module")
def design():
    return parse_landxml(DEMO.read_text(encoding="utf-8"))


def _run(design, east_m, seed, **sim):
    d = design.translated(east_m, 0.0)
    s = simulate_survey(d, SimulationConfig(**{**SHORT, **sim}, seed=seed))
    return d, s


def _errors(design, sim):
    r = process_session(sim.session, design, with_observability=False)
    tj = r.trajectory
    return r, track_errors(tj.t_s, tj.distance_m, tj.enh_m, tj.sigma_enh_m, sim.truth, cov_EN_m2=tj.cov_EN_m2)


def test_simulated_site_has_the_convergence_of_the_issue(design):
    _, s = _run(design, OFF_M, 1, length_m=60.0, static_s=30.0)
    g = s.truth.geometry.grid
    # gamma ~ dlon sin(lat): 200 km at 28 deg N is 0.96 deg; k ~ k0 (1 + x^2 / 2R^2)
    assert math.degrees(g.convergence_rad) == pytest.approx(0.96, abs=0.005)
    dlon = g.longitude_rad - math.radians(117.0)
    assert g.convergence_rad == pytest.approx(dlon * math.sin(g.latitude_rad), rel=2e-3)
    assert g.point_scale == pytest.approx(0.9996 * (1 + 200e3 ** 2 / (2 * g.radius_m ** 2)), abs=2e-6)
    assert math.degrees(s.session.meta.latitude_rad) == pytest.approx(28.01, abs=0.01)
    assert s.session.meta.crs == CRS


def test_off_meridian_site_is_as_accurate_as_on_it_and_within_its_sigmas(design):
    q_lat, q_vert = [], []
    for seed in (11, 12, 13):
        d_on, s_on = _run(design, 0.0, seed)
        d_off, s_off = _run(design, OFF_M, seed)
        r_on, e_on = _errors(d_on, s_on)
        r_off, e_off = _errors(d_off, s_off)
        assert r_off.summary["fixes_rejected"] == 0 and r_on.summary["fixes_rejected"] == 0
        # the same seed on and off the meridian: the same errors to a few micrometres
        for a, b in zip(e_on.rms_m(), e_off.rms_m()):
            assert abs(a - b) < 2e-5, (seed, e_on.rms_m(), e_off.rms_m())
        q_lat.append(e_off.lateral_m / e_off.sigma_lateral_m)
        q_vert.append(e_off.vertical_m / e_off.sigma_vertical_m)
        assert max(e_off.rms_m()) < 1.5e-3
    for q in (np.concatenate(q_lat), np.concatenate(q_vert)):
        assert 0.5 < np.sqrt(np.mean(q ** 2)) < 1.5
        assert np.mean(np.abs(q) > 3.0) < 0.02


def test_without_the_crs_the_session_is_refused_naming_the_convergence(design):
    d, s = _run(design, OFF_M, 5, crs_in_session=False)
    assert s.session.meta.crs is None
    with pytest.raises(GridRotationError) as exc:
        process_session(s.session, d, with_observability=False)
    msg = str(exc.value)
    assert "grid convergence" in msg and "crs" in msg and "rejected" in msg
    deg = float(msg.split("turned by ")[1].split(" deg")[0])
    # the fit holds the convergence plus the gyrocompass heading error of this short session
    assert deg == pytest.approx(-0.96, abs=0.1)


def test_fix_rotation_recovers_a_turned_path(design):
    # two independent routes to the same angle: the Procrustes fit of the fixes against the dead
    # reckoning, and the convergence the simulator put between them
    d, s = _run(design, OFF_M, 5, crs_in_session=False)
    from trolley.deadreckoning import dead_reckon, static_alignment
    m = s.session.meta
    ses = s.session
    al = static_alignment(ses.imu_t_s, ses.imu_w_rad_s, ses.imu_f_m_s2, m.static_s, m.latitude_rad,
                          m.trolley.imu_misalignment_rad, gyro_bias_rad_s=m.imu.gyro_bias_instability_rad_s,
                          accel_bias_m_s2=m.imu.accel_bias_m_s2)
    dr = dead_reckon(ses.imu_t_s, ses.imu_w_rad_s, ses.odo_t_s, ses.odo_distance_m, al, m.latitude_rad,
                     m.height_m, m.trolley.imu_misalignment_rad, 40)
    e = ses.fixes.enh_m - ses.fixes.enh_m[0]
    fix_ned = np.column_stack([e[:, 1], e[:, 0], -e[:, 2]])
    blocks = np.clip(np.searchsorted(dr.t_s, ses.fixes.t_s), 0, dr.t_s.size - 1)
    theta, scale, before, after = fix_rotation(dr, blocks, fix_ned, m.trolley.prism_lever_arm_m)
    g = s.truth.geometry.grid
    # (plus the gyrocompass heading error, about 1.5 mrad in this 300 s alignment)
    assert theta == pytest.approx(-g.convergence_rad, abs=2.5e-3)
    assert scale == pytest.approx(g.combined_scale, abs=1e-3)
    assert after < 0.05 * before


def test_process_cli_exits_2_without_crs_and_succeeds_with_it(design, tmp_path):
    d, s = _run(design, OFF_M, 5, crs_in_session=False, length_m=240.0)
    xml = landxml_text(d)
    folder = tmp_path / "session"
    write_session(folder, dataclasses.replace(s.session, meta=dataclasses.replace(
        s.session.meta, design_alignment="alignment.xml")), xml)
    r = runner.invoke(app, ["process", str(folder), "--out", str(tmp_path / "out")])
    assert r.exit_code == 2, r.output
    assert "grid convergence" in r.stderr and "Traceback" not in r.output
    assert not (tmp_path / "out").exists()
    # the crew gives the CRS (and no latitude: it comes from the CRS at the fixes)
    text = (folder / "session.toml").read_text()
    text = "\n".join(line for line in text.splitlines() if not line.startswith("latitude_deg"))
    (folder / "session.toml").write_text(text.replace("[site]", f'[site]\ncrs = "{CRS}"', 1))
    back = read_session(folder)
    assert math.degrees(back.meta.latitude_rad) == pytest.approx(28.01, abs=0.01)
    r = runner.invoke(app, ["process", str(folder), "--out", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    # the survey sheet carries the CRS, the scale factor and the convergence
    import json

    from openpyxl import load_workbook

    from survey.export import export_outputs
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["crs"] == CRS and summary["grid_convergence_deg"] == pytest.approx(0.96, abs=0.01)
    export_outputs(tmp_path / "out", tmp_path / "survey.xlsx", tmp_path / "table.csv", tmp_path / "plots")
    wb = load_workbook(tmp_path / "survey.xlsx")
    sheet = {row[0].value: row[1].value for row in wb["Summary"].iter_rows(min_row=1, max_col=2)}
    from survey.surveyheader import NOT_GIVEN
    assert sheet["Coordinate system"] == CRS and sheet["Height datum"] == NOT_GIVEN
    grid = sheet["Grid convergence and scale"]
    assert f"convergence {summary['grid_convergence_deg']:+.6f} deg" in grid
    assert f"point scale factor {summary['grid_scale_factor']:.9f}" in grid
    assert f"combined scale {summary['grid_combined_scale']:.9f}" in grid
    assert 1.00008 < summary["grid_scale_factor"] < 1.0001  # k0 (1 + x^2 / 2R^2) at 200 km


def test_session_toml_crs_round_trip_and_errors(tmp_path):
    from survey.sessionio import _parse_meta
    from trolley.session import SessionMeta

    meta = SessionMeta(latitude_rad=float("nan"), crs=CRS, vertical_datum="Yellow Sea 1985 height")
    text = session_toml_text(meta)
    assert "latitude_deg" not in text
    back = _parse_meta(text)
    assert back.crs == CRS and back.vertical_datum == "Yellow Sea 1985 height"
    assert math.isnan(back.latitude_rad)
    bad = text.replace(CRS, "EPSG:4326")
    with pytest.raises(SessionFormatError, match=r"key site.crs: .*not a projected CRS"):
        _parse_meta(bad)
    # without a CRS the latitude stays required
    with pytest.raises(SessionFormatError, match="site.latitude_deg"):
        _parse_meta(text.replace(f'crs = "{CRS}"', ""))
