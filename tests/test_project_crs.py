"""The project CRS: ``trolley project set-crs``, the store's site grid, total-station distances
reduced to the grid (free station and fixes), and the survey sheet's CRS block."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from survey.cli import app
from survey.store import ControlPoint, ProjectSettings, ProjectStore
from trolley.projection import gaussian_radius_m, site_factors
from trolley.resection import (PolarModel, ResectionConfig, observations_from_station, point_from_observation,
                               resect)

runner = CliRunner()
CRS = "EPSG:32650"
SITE = np.array([700000.0, 3100000.0, 500.0])  # 200 km east of 117 deg E, 28 deg N, 500 m up


def run(*args: str, code: int = 0):
    res = runner.invoke(app, list(args))
    assert res.exit_code == code, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr
    return res


def cpiii(centre=SITE, n=4):
    """CPIII pairs every 60 m along a straight line running grid north-east through ``centre``."""
    pts = []
    az = math.radians(40.0)
    for i in range(n):
        s = (i - (n - 1) / 2) * 60.0
        for side in (-3.2, 3.2):
            e = centre[0] + s * math.sin(az) + side * math.cos(az)
            nn = centre[1] + s * math.cos(az) - side * math.sin(az)
            pts.append(ControlPoint(f"CP{i:02d}{'L' if side < 0 else 'R'}", e, nn, centre[2] + 0.4))
    return pts


def test_distance_reduction_hand_case():
    # combined scale by hand: k = k0 (1 + x^2 / 2R^2 + x^4 / 24R^4), x the ellipsoid distance
    # from the central meridian (at 200 km the x^4 term is 4e-8); height reduction R / (R + h)
    g = site_factors(CRS, SITE[None, :])
    R = gaussian_radius_m(g.latitude_rad)
    x = 200000.0 / 0.9996
    k = 0.9996 * (1 + x * x / (2 * R * R) + x ** 4 / (24 * R ** 4))
    kc = k * R / (R + 500.0)
    assert g.combined_scale == pytest.approx(kc, abs=5e-9)
    assert kc == pytest.approx(1.0000152, abs=1e-7)  # +94 ppm of projection, -78 ppm of height
    # a 100.000 m ground distance due east from the station lies 100 k m east on the grid
    station = SITE + [1.0, 2.0, 1.5]
    grid = station + [100.0 * kc, 0.0, -0.2]
    # through the polar model: observation of a ground distance -> grid point
    obs = observations_from_station(station, 0.3, grid, PolarModel(curvature_refraction=False, grid_scale=kc))
    assert math.hypot(100.0, 0.2) == pytest.approx(float(obs.slope_distance_m[0]), abs=1e-9)
    back = point_from_observation(station, 0.3, obs, PolarModel(curvature_refraction=False, grid_scale=kc))
    assert np.allclose(back[0], grid, atol=1e-9)


def test_free_station_with_and_without_the_reduction():
    pts = cpiii()
    enh = np.array([[p.e_m, p.n_m, p.h_m] for p in pts])
    g = site_factors(CRS, enh)
    station = enh.mean(axis=0) + [4.0, -2.0, 1.1]
    ground = PolarModel(curvature_refraction=False, grid_scale=g.combined_scale)
    obs = observations_from_station(station, 1.1, enh, ground)  # what the instrument measures
    ids = [p.point_id for p in pts]
    settings = ProjectSettings(crs=CRS, polar_model=PolarModel(curvature_refraction=False))
    res = resect(ids, enh, obs, settings.resection_config(g.combined_scale))
    assert np.allclose(res.station_enh_m, station, atol=1e-7)
    # unreduced: the ground distances are 1.3e-5 too short for the grid, the network does not close
    flat = resect(ids, enh, obs, settings.resection_config())
    worst = max(max(abs(r.across_m), abs(r.along_m)) for r in flat.residuals)
    assert worst > 10 * max(max(abs(r.across_m), abs(r.along_m)) for r in res.residuals)
    assert flat.sigma0 > 5 * max(res.sigma0, 1e-3)


def test_store_site_grid_and_new_session_meta(tmp_path):
    st = ProjectStore.create(tmp_path, "p", ProjectSettings())
    with st:
        assert st.site_grid() is None
        st.add_cpiii_points(cpiii())
        import dataclasses
        st.set_settings(dataclasses.replace(st.settings(), crs=CRS, vertical_datum="Yellow Sea 1985"))
        g = st.site_grid()
        enh = np.array([[p.e_m, p.n_m, p.h_m] for p in st.cpiii_points()])
        assert g == site_factors(CRS, enh)
        rec = st.create_session("s1")
        assert rec.meta.crs == CRS and rec.meta.vertical_datum == "Yellow Sea 1985"
        assert rec.meta.latitude_rad == g.latitude_rad


def test_set_crs_cli(tmp_path):
    root = str(tmp_path)
    run("project", "new", "p", "--root", root)
    csv = tmp_path / "cp.csv"
    csv.write_text("id,E_m,N_m,H_m\n" + "".join(f"{p.point_id},{p.e_m},{p.n_m},{p.h_m}\n" for p in cpiii()))
    run("project", "import-cpiii", str(csv), "--project", "p", "--root", root)
    r = run("project", "set-crs", "p", "EPSG:32650", "--vertical-datum", "Yellow Sea 1985", "--root", root)
    assert "grid convergence +0.95" in r.stderr and "combined scale 1.0000" in r.stderr
    doc = json.loads(run("project", "show", "p", "--root", root, "--json").stdout)
    assert doc["settings"]["crs"] == "EPSG:32650" and doc["settings"]["vertical_datum"] == "Yellow Sea 1985"
    gr = doc["grid"]
    assert gr["convergence_deg"] == pytest.approx((gr["longitude_deg"] - 117.0) * math.sin(math.radians(
        gr["latitude_deg"])), rel=2e-3)  # dlon sin(lat)
    assert gr["convergence_deg"] == pytest.approx(0.96, abs=0.01)
    assert doc["settings"]["latitude_rad"] == pytest.approx(math.radians(doc["grid"]["latitude_deg"]), abs=1e-12)
    # a compound CRS brings its vertical datum
    run("project", "set-crs", "p", "EPSG:32650+5773", "--root", root)  # + EGM96 height
    doc = json.loads(run("project", "show", "p", "--root", root, "--json").stdout)
    assert doc["settings"]["vertical_datum"] == "EGM96 height"
    r = run("project", "set-crs", "p", "EPSG:4326", "--root", root, code=2)
    assert "not a projected CRS" in r.stderr
    r = run("project", "set-crs", "p", "nonsense", "--root", root, code=2)
    assert "not a coordinate reference system" in r.stderr
    r = run("project", "set-crs", "p", "EPSG:32650", "--vertical-datum", "a\nb", "--root", root, code=2)
    assert "--vertical-datum: control characters" in r.stderr
    # show gives the latitude the sessions use: the CRS's at the CPIII centroid
    lat = json.loads(run("project", "show", "p", "--root", root, "--json").stdout)["grid"]["latitude_deg"]
    r = run("project", "show", "p", "--root", root)
    assert f"latitude {lat:.4f} deg (the CRS's at" in r.stdout, r.stdout


def test_survey_sheet_shows_the_crs(tmp_path):
    from survey.track_reader import read_summary_json

    (tmp_path / "summary.json").write_text(json.dumps({
        "crs": CRS, "vertical_datum": "Yellow Sea 1985", "grid_scale_factor": 1.000092,
        "grid_convergence_deg": 0.9589, "grid_combined_scale": 1.000084, "fixes_used": 3}))
    info = read_summary_json(tmp_path / "summary.json")
    assert (info.crs, info.vertical_datum, info.grid_scale_factor, info.grid_convergence_deg) == (
        CRS, "Yellow Sea 1985", 1.000092, 0.9589)
    assert info.grid_combined_scale == 1.000084 and "crs" not in info.extra
    empty = tmp_path / "e.json"
    empty.write_text("{}")
    e = read_summary_json(empty)
    assert e.crs == "" and math.isnan(e.grid_scale_factor)


def _design_with(cs_element: str) -> str:
    from trolley.alignment import Alignment, HorizontalAlignment, Line
    from trolley.landxml import landxml_text

    h = HorizontalAlignment.from_elements(SITE[0] - 100.0, SITE[1] - 100.0, 0.7, [Line(300.0)])
    xml = landxml_text(Alignment(h, name="up"))
    return xml.replace("</Units>", "</Units>\n  " + cs_element, 1) if cs_element else xml


def test_import_alignment_reads_the_landxml_coordinate_system(tmp_path):
    root = str(tmp_path)
    run("project", "new", "p", "--root", root, "--no-toml")
    csv = tmp_path / "cp.csv"
    csv.write_text("id,E_m,N_m,H_m\n" + "".join(f"{p.point_id},{p.e_m},{p.n_m},{p.h_m}\n" for p in cpiii()))
    run("project", "import-cpiii", str(csv), "--project", "p", "--root", root)
    f = tmp_path / "design.xml"
    f.write_text(_design_with('<CoordinateSystem name="WGS 84 / UTM zone 50N" epsgCode="32650" '
                              'verticalDatum="Yellow Sea 1985"/>'))
    r = run("project", "import-alignment", str(f), "--project", "p", "--root", root)
    assert "the project's CRS is now EPSG:32650" in r.stderr and "grid convergence +0.95" in r.stderr
    doc = json.loads(run("project", "show", "p", "--root", root, "--json").stdout)
    assert doc["settings"]["crs"] == "EPSG:32650" and doc["settings"]["vertical_datum"] == "Yellow Sea 1985"
    assert doc["settings"]["latitude_rad"] == pytest.approx(math.radians(doc["grid"]["latitude_deg"]), abs=1e-12)
    # the same CRS again: nothing to say; another one: the project keeps its own, with a note
    r = run("project", "import-alignment", str(f), "--project", "p", "--root", root)
    assert "CoordinateSystem" not in r.stderr
    f.write_text(_design_with('<CoordinateSystem epsgCode="urn:ogc:def:crs:EPSG::32651"/>'))
    r = run("project", "import-alignment", str(f), "--project", "p", "--root", root)
    assert "differs from the project's CRS EPSG:32650" in r.stderr
    assert json.loads(run("project", "show", "p", "--root", root, "--json").stdout)["settings"]["crs"] == "EPSG:32650"
    # a name alone, or a geographic CRS: a note, nothing changed, the design still imported
    run("project", "new", "q", "--root", root, "--no-toml")
    for cs, says in (('<CoordinateSystem name="Local grid"/>', "gives no epsgCode"),
                     ('<CoordinateSystem epsgCode="4326"/>', "not a projected CRS")):
        f.write_text(_design_with(cs))
        r = run("project", "import-alignment", str(f), "--project", "q", "--root", root)
        assert says in r.stderr and "alignment 'up'" in r.stdout
        assert json.loads(run("project", "show", "q", "--root", root, "--json").stdout)["settings"]["crs"] is None


def test_project_new_checks_the_toml_crs(tmp_path):
    import shutil

    from survey.commands.simulate import _REPO_DEMO

    folder = tmp_path / "d"
    shutil.copytree(_REPO_DEMO, folder)
    toml = (folder / "project.toml").read_text()
    (folder / "project.toml").write_text(toml.replace("[site]\n", '[site]\ncrs = "EPSG:4326"\n', 1))
    r = run("project", "new", "d", "--root", str(tmp_path), code=2)
    assert "key site.crs" in r.stderr and "not a projected CRS" in r.stderr
    assert not (folder / "project.sqlite").exists()
    (folder / "project.toml").write_text(toml.replace("[site]\n", '[site]\ncrs = "EPSG:32650"\n', 1))
    run("project", "new", "d", "--root", str(tmp_path))
    doc = json.loads(run("project", "show", "d", "--root", str(tmp_path), "--json").stdout)
    assert doc["settings"]["crs"] == "EPSG:32650"
    # the demo lies on the central meridian of UTM 50N: no convergence to speak of, k ~ k0
    assert abs(doc["grid"]["convergence_deg"]) < 0.01 and doc["grid"]["point_scale"] == pytest.approx(0.9996, abs=1e-6)
    assert doc["settings"]["latitude_rad"] == pytest.approx(math.radians(doc["grid"]["latitude_deg"]), abs=1e-12)
