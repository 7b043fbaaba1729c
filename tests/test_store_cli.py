"""``trolley project ...`` commands, and the raw session folder <-> store round trip."""
from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from survey.cli import app
from survey.store import ProjectSettings, ProjectStore
from trolley.session import Fixes, RawSession

runner = CliRunner()


def run(*args: str, code: int = 0):
    res = runner.invoke(app, list(args))
    assert res.exit_code == code, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr
    return res


def design_xml() -> str:
    from trolley.alignment import Alignment, Arc, Clothoid, HorizontalAlignment, Line
    from trolley.landxml import landxml_text

    h = HorizontalAlignment.from_elements(500000.0, 3100000.0, 0.6, [
        Line(100.0), Clothoid(60.0, 0.0, 1 / 2000.0), Arc(150.0, 1 / 2000.0), Clothoid(60.0, 1 / 2000.0, 0.0),
        Line(80.0)], start_chainage_m=1000.0)
    import datetime as dt

    return landxml_text(Alignment(h, name="up-line"), timestamp=dt.datetime(2026, 1, 1, tzinfo=dt.timezone.utc))


def small_session(rng, with_gauge=True) -> RawSession:
    n = 2000
    t = np.arange(n) * 0.005
    gt = np.arange(0, n, 10) * 0.005
    return RawSession(
        meta=ProjectSettings().session_meta(),
        imu_t_s=t, imu_w_rad_s=rng.normal(0, 1e-4, (n, 3)),
        imu_f_m_s2=rng.normal(0, 1e-2, (n, 3)) + [0, 0, -9.79],
        odo_t_s=t, odo_distance_m=np.cumsum(rng.uniform(0, 2e-3, n)),
        fixes=Fixes(np.array([0.5, 9.0]), np.array(["CP0101", "CP0201"], dtype=object),
                    np.array([[500000.1234, 3100000.5678, 45.1234], [500030.1, 3100040.2, 45.3]]),
                    np.full((2, 3), 6e-4)),
        gauge_t_s=gt if with_gauge else None,
        gauge_m=1.435 + rng.normal(0, 2e-4, gt.size) if with_gauge else None)


def test_new_import_show(tmp_path):
    root = str(tmp_path)
    run("project", "new", "line7", "--root", root, "--imu", "fog", "--latitude-deg", "31.5")
    run("project", "new", "line7", "--root", root, code=2)
    cp = tmp_path / "cp.csv"
    cp.write_text("id,E_m,N_m,H_m\nCP0101,500001.0,3100002.0,45.1\nCP0102,500004.5,3100001.0,45.2\n", encoding="utf-8")
    res = run("project", "import-cpiii", str(cp), "--project", "line7", "--root", root)
    # the result on stdout, as every command's (it was on stderr)
    assert res.stdout == f"{cp}: 2 CPIII points imported; the project has 2\n" and res.stderr == ""
    bad = tmp_path / "bad.gsi"
    bad.write_text("*110001+000000000000CP99 81..01+0000000000012345 82..06+0000000000012345 "
                   "83..06+0000000000012345 \n", encoding="utf-8")
    res = run("project", "import-cpiii", str(bad), "--project", "line7", "--root", root, code=2)
    assert f"{bad}:1:" in res.stderr and "nothing imported" in res.stderr
    xml = tmp_path / "design.xml"
    xml.write_text(design_xml(), encoding="utf-8")
    res = run("project", "import-alignment", str(xml), "--project", "line7", "--root", root)
    assert res.stdout == f"{xml}: alignment 'up-line', 5 elements, chainage 1000.000 .. 1450.000 m\n"
    assert "5 elements" not in res.stderr
    # with --json stdout is the JSON object alone, the line goes to stderr
    res = run("project", "import-alignment", str(xml), "--project", "line7", "--root", root, "--json")
    assert json.loads(res.stdout)["elements"] == 5 and "5 elements" in res.stderr
    broken = tmp_path / "broken.xml"
    broken.write_text(design_xml().replace("<CoordGeom>", "<CoordGeom><Spiral spiType='bloss'/>"), encoding="utf-8")
    res = run("project", "import-alignment", str(broken), "--project", "line7", "--root", root, code=2)
    assert "broken.xml" in res.stderr and "nothing imported" in res.stderr
    res = run("project", "show", "line7", "--root", root, "--json")
    doc = json.loads(res.stdout)
    assert doc["cpiii"]["count"] == 2
    assert doc["cpiii"]["min_enh_m"] == [500001.0, 3100001.0, 45.1]
    assert doc["alignment"]["elements"] == 5 and doc["alignment"]["chainage_end_m"] == pytest.approx(1450.0)
    assert doc["settings"]["imu"]["name"] == "fog"
    assert doc["settings"]["latitude_rad"] == pytest.approx(np.deg2rad(31.5))
    res = run("project", "show", "line7", "--root", root)
    assert "2 points" in res.stdout and "up-line" in res.stdout
    with ProjectStore.open_project(tmp_path, "line7") as s:
        assert s.alignment().landxml_text == design_xml()  # verbatim
    res = run("project", "show", "nope", "--root", root, code=2)
    assert "no project 'nope'" in res.stderr


@pytest.mark.parametrize("with_design, with_gauge", [(True, True), (False, False)])
def test_session_folder_round_trip_through_store(tmp_path, with_design, with_gauge):
    from survey.sessionio import write_session

    src = tmp_path / "src"
    write_session(src, small_session(np.random.default_rng(4), with_gauge), design_xml() if with_design else None)
    root = str(tmp_path / "projects")
    run("project", "new", "p", "--root", root)
    res = run("project", "import-session", str(src), "--project", "p", "--root", root, "--session", "s1")
    assert "2000 IMU samples" in res.stderr and "2 fixes" in res.stderr
    run("project", "import-session", str(src), "--project", "p", "--root", root, "--session", "s1", code=2)
    out = tmp_path / "out"
    run("project", "export-session", "--project", "p", "--session", "s1", "--out", str(out), "--root", root)
    names = sorted(p.name for p in src.iterdir())
    assert names == sorted(p.name for p in out.iterdir() if p.name != ".made-by-trolley")
    assert ("alignment.xml" in names) == with_design and ("gauge.csv" in names) == with_gauge
    for name in names:
        assert (out / name).read_bytes() == (src / name).read_bytes(), name
    # exporting again onto an existing folder is refused, nothing half-written
    res = run("project", "export-session", "--project", "p", "--session", "s1", "--out", str(out), "--root", root,
              code=2)
    assert "already exists" in res.stderr
    # --overwrite replaces a folder export-session made, never another one (here the source)
    run("project", "export-session", "--project", "p", "--session", "s1", "--out", str(out), "--root", root,
        "--overwrite")
    before = {p.name: p.read_bytes() for p in src.iterdir()}
    res = run("project", "export-session", "--project", "p", "--session", "s1", "--out", str(src), "--root", root,
              "--overwrite", code=2)
    assert "not made by" in res.stderr and {p.name: p.read_bytes() for p in src.iterdir()} == before


def test_rejected_fix_is_not_exported(tmp_path):
    from survey.sessionio import read_session, write_session

    src = tmp_path / "src"
    write_session(src, small_session(np.random.default_rng(5)))
    root = tmp_path / "projects"
    run("project", "new", "p", "--root", str(root))
    run("project", "import-session", str(src), "--project", "p", "--root", str(root), "--session", "s")
    with ProjectStore.open_project(root, "p") as s:
        sid = s.session("s").session_id
        first = s.fixes(sid)[0]
        s.decide_fix(first.fix_id, False, "prism not levelled")
    run("project", "export-session", "--project", "p", "--session", "s", "--out", str(tmp_path / "out"),
        "--root", str(root))
    back = read_session(tmp_path / "out")
    assert list(back.fixes.point) == ["CP0201"]


def test_import_session_bad_folder(tmp_path):
    from survey.sessionio import write_session

    root = str(tmp_path / "projects")
    run("project", "new", "p", "--root", root)
    src = tmp_path / "src"
    write_session(src, small_session(np.random.default_rng(6)))
    text = (src / "odometer.csv").read_text().splitlines()
    text[5] = "0.02,abc"
    (src / "odometer.csv").write_text("\n".join(text) + "\n")
    res = run("project", "import-session", str(src), "--project", "p", "--root", root, code=2)
    assert "odometer.csv" in res.stderr and "row 6" in res.stderr
    with ProjectStore.open_project(tmp_path / "projects", "p") as s:
        assert s.sessions() == []


def test_new_from_project_toml(tmp_path):
    folder = tmp_path / "line9"
    folder.mkdir()
    (folder / "alignment.xml").write_text(design_xml(), encoding="utf-8")
    (folder / "cp.csv").write_text("id,E_m,N_m,H_m\nCP1,500001.0,3100002.0,45.1\nCP2,500004.5,3100001.0,45.2\n",
                                   encoding="utf-8")
    (folder / "project.toml").write_text(
        'name = "line9"\n[site]\nlatitude_deg = 40.0\nheight_m = 12.0\n[imu]\npreset = "mems"\n'
        '[trolley]\nprism_lever_arm_m = [0.1, 0.0, -0.7]\nrail_spacing_m = 1.507\n'
        '[simulation]\nstatic_s = 120.0\n[design]\nalignment = "alignment.xml"\ncpiii = "cp.csv"\n'
        '[totalstation]\ncpiii_prism_constant_mm = -2.5\ntrolley_prism_constant_mm = 23.1\n',
        encoding="utf-8")
    res = run("project", "new", "line9", "--root", str(tmp_path), "--height", "13.5")
    assert "2 CPIII points" in res.stderr and "5 elements" in res.stderr
    with ProjectStore.open_project(tmp_path, "line9") as s:
        st = s.settings()
        assert st.imu.name == "mems" and st.height_m == 13.5 and st.static_s == 120.0
        assert st.latitude_rad == pytest.approx(np.deg2rad(40.0))
        np.testing.assert_array_equal(st.trolley.prism_lever_arm_m, [0.1, 0.0, -0.7])
        assert st.trolley.rail_spacing_m == 1.507
        assert len(s.cpiii_points()) == 2 and s.alignment().name == "up-line"
        # mm in the file, m in the store
        assert (st.cpiii_prism_constant_m, st.trolley_prism_constant_m) == pytest.approx((-0.0025, 0.0231), abs=1e-15)
    # the crew changes the trolley prism later; a value the session cannot use changes nothing
    run("project", "set", "trolley_prism_constant_mm", "17.5", "--project", "line9", "--root", str(tmp_path))
    for value, message in (("nan", "must be a finite number, got nan"), ("0.0231", None),
                           ("-100.5", "must be >= -100, got -100.5"), ("23,1", "must be a number in mm, got '23,1'")):
        if message is not None:
            res = run("project", "set", "cpiii_prism_constant_mm", value, "--project", "line9", "--root", str(tmp_path),
                      code=2)
            assert f"error: cpiii_prism_constant_mm: {message}" in res.stderr
    with ProjectStore.open_project(tmp_path, "line9") as s:
        st = s.settings()
    assert (st.cpiii_prism_constant_m, st.trolley_prism_constant_m) == pytest.approx((-0.0025, 0.0175), abs=1e-15)
    # a bad CPIII file named by project.toml: an error and no project at all
    other = tmp_path / "line10"
    other.mkdir()
    for f in ("alignment.xml", "project.toml"):
        (other / f).write_text((folder / f).read_text())
    (other / "cp.csv").write_text("id,E_m,N_m,H_m\nCP1,1,2,3\nCP1,1,2,3\n", encoding="utf-8")
    res = run("project", "new", "line10", "--root", str(tmp_path), code=2)
    assert "cp.csv:3: duplicate point id" in res.stderr
    assert not (other / "project.sqlite").exists()
    run("project", "new", "line10", "--root", str(tmp_path), "--no-toml")


@pytest.mark.parametrize("edit, message", [
    (("height_m = 12.0", "height_m = nan"), "key site.height_m: must be a finite number, got nan"),
    (("height_m = 12.0", "height_m = -1e9"), "key site.height_m: must be within -1000..10000 m"),
    (("static_s = 120.0", "static_s = -5.0"), "key simulation.static_s: must be >= 0, got -5.0"),
    (("static_s = 120.0", "static_s = 120.0\nfix_sigma_m = nan"), "key simulation.fix_sigma_m: must be a finite"),
    (("static_s = 120.0", "static_s = 120.0\nfixes_per_stop = 0"), "key simulation.fixes_per_stop: must be > 0"),
    (("rail_spacing_m = 1.507", "rail_spacing_m = 0.0"), "key trolley.rail_spacing_m: must be > 0"),
    (("[0.1, 0.0, -0.7]", "[0.1, nan, -0.7]"), "key trolley.prism_lever_arm_m: must be 3 finite numbers"),
    # a prism constant typed in tenths of a mm, in m, as text, or under a key the session never reads
    (("static_s = 120.0", "static_s = 120.0\n[totalstation]\ntrolley_prism_constant_mm = 231"),
     "key totalstation.trolley_prism_constant_mm: must be <= 100, got 231 (mm, Leica's convention"),
    (("static_s = 120.0", "static_s = 120.0\n[totalstation]\ncpiii_prism_constant_mm = nan"),
     "key totalstation.cpiii_prism_constant_mm: must be a finite number, got nan"),
    (("static_s = 120.0", "static_s = 120.0\n[totalstation]\ncpiii_prism_constant_mm = '23.1'"),
     "key totalstation.cpiii_prism_constant_mm: must be a finite number, got '23.1'"),
    (("static_s = 120.0", "static_s = 120.0\n[totalstation]\nprism_constant_mm = 23.1"),
     "key totalstation.prism_constant_mm: unknown setting (the keys are cpiii_prism_constant_mm, "
     "trolley_prism_constant_mm)"),
])
def test_settings_a_session_cannot_use_are_refused_when_the_project_is_made(tmp_path, edit, message):
    # (they were stored, and the crew's recorded session then failed at its end: no track, no sheet)
    folder = tmp_path / "p"
    folder.mkdir()
    (folder / "alignment.xml").write_text(design_xml(), encoding="utf-8")
    (folder / "project.toml").write_text(
        ('[site]\nlatitude_deg = 40.0\nheight_m = 12.0\n[trolley]\nprism_lever_arm_m = [0.1, 0.0, -0.7]\n'
         'rail_spacing_m = 1.507\n[simulation]\nstatic_s = 120.0\n[design]\nalignment = "alignment.xml"\n')
        .replace(*edit), encoding="utf-8")
    res = run("project", "new", "p", "--root", str(tmp_path), code=2)
    assert message in res.stderr and "project.toml" in res.stderr
    assert not (folder / "project.sqlite").exists()


def test_height_option_must_be_a_plausible_number(tmp_path):
    for value, message in (("nan", "must be a finite number, got nan"), ("inf", "must be a finite number, got inf"),
                           ("-1e9", "must be >= -1000, got -1e+09")):
        res = run("project", "new", "p", "--root", str(tmp_path), "--no-toml", "--height-m", value, code=2)
        assert f"error: --height-m: {message}" in res.stderr
    assert not (tmp_path / "p" / "project.sqlite").exists()


def test_resection_table_shows_mm_and_arcsec():
    import io

    from rich.console import Console

    from survey.commands.project import resection_table
    from trolley.resection import observations_from_station, resect

    ids = ["A", "B", "C", "D", "E"]
    pts = np.array([[10.0, 40, 1], [45, 5, -1], [-30, -35, 0.5], [-40, 20, 0], [20, -45, 2]])
    wrong = pts.copy()
    wrong[1, 2] += 0.004  # 4 mm high
    res = resect(ids, pts, observations_from_station(np.zeros(3), 0.3, wrong))
    buf = io.StringIO()
    Console(file=buf, width=200).print(resection_table(res))
    text = buf.getvalue()
    row_b = next(line for line in text.splitlines() if line.strip("│ ").startswith("B "))
    assert f"{res.residuals[1].height_m * 1e3:+.2f}" in row_b
    assert f"{res.residuals[1].zenith_rad / (np.pi / 180 / 3600):+.1f}" in row_b
    assert "standardized residual" in row_b
    assert "sigma0" in text and "dof" in text
    assert "suggests dropping or re-measuring B" in text
    # the blunder makes sigma0 > 1: the station's 1-sigmas shown are those the fixes carry, sigma0 times
    # the a priori ones
    assert res.sigma0 > 1.5
    shown = " ".join(text.split())
    e_sigma = np.sqrt(res.covariance[0, 0]) * res.sigma0 * 1e3
    assert f"(1-sigma {e_sigma:.2f} / " in shown and "the 1-sigmas are scaled by sigma0" in shown


def test_tolerance_set_is_checked_when_the_project_is_created(tmp_path):
    root = str(tmp_path)
    res = run("project", "new", "p", "--root", root, "--tolerance-set", "hsr_static_typo", code=2)
    assert "--tolerance-set" in res.stderr and "hsr_static_typo" in res.stderr
    assert "hsr_ballastless_static" in res.stderr  # the built-in names are listed
    assert not (tmp_path / "p" / "project.sqlite").exists()  # nothing created
    run("project", "new", "p", "--root", root, "--tolerance-set", "en13848_5_alert")
    with ProjectStore.open_project(tmp_path, "p") as s:
        assert s.settings().tolerance_set == "en13848_5_alert"


def test_export_leaves_out_the_data_before_a_restarted_alignment(tmp_path):
    """The same crop as the final processing (ProjectStore.raw_session): nothing before the static
    alignment that succeeded, so `trolley process` on the export gives the session's final track."""
    from survey.sessionio import read_session, write_session
    from survey.store import SessionEvent

    src = tmp_path / "src"
    write_session(src, small_session(np.random.default_rng(6)))
    full = read_session(src)  # as written (the CSV text rounds)
    root = tmp_path / "projects"
    run("project", "new", "p", "--root", str(root))
    run("project", "import-session", str(src), "--project", "p", "--root", str(root), "--session", "s")
    with ProjectStore.open_project(root, "p") as s:
        sid = s.session("s").session_id
        s.add_event(sid, SessionEvent(1.0, "alignment_restart", "2.0"))
        s.add_event(sid, SessionEvent(5.0, "aligned", json.dumps({"static_start_s": 2.0, "static_s": 3.0})))
        assert s.survey_start_s(sid) == 2.0
    run("project", "export-session", "--project", "p", "--session", "s", "--out", str(tmp_path / "out"),
        "--root", str(root))
    back = read_session(tmp_path / "out")
    keep = full.imu_t_s >= 2.0
    assert np.array_equal(back.imu_t_s, full.imu_t_s[keep]) and np.array_equal(back.imu_w_rad_s, full.imu_w_rad_s[keep])
    assert np.array_equal(back.odo_t_s, full.odo_t_s[full.odo_t_s >= 2.0])
    assert np.array_equal(back.gauge_t_s, full.gauge_t_s[full.gauge_t_s >= 2.0])
    assert list(back.fixes.point) == ["CP0201"]  # the fix at 0.5 s was before the alignment
