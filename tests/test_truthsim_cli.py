"""``trolley simulate`` and the demo project (project.toml, cpiii.csv)."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from survey.cli import app
from survey.sessionio import read_design, read_session, read_truth_csv

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "projects" / "demo"


def _run(args):
    return CliRunner().invoke(app, ["simulate", *args])


def test_simulate_writes_a_readable_session(tmp_path):
    out = tmp_path / "sess"
    r = _run(["--out", str(out), "--project", str(DEMO), "--length-m", "120", "--static-s", "10",
              "--rate-hz", "50", "--seed", "7", "--imu", "fog"])
    assert r.exit_code == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["imu"] == "fog" and summary["stops"] == 3 and summary["fixes"] == 3
    assert sorted(p.name for p in out.iterdir()) == [
        ".made-by-trolley", "alignment.xml", "fixes.csv", "gauge.csv", "imu.csv", "odometer.csv", "session.toml",
        "truth.csv"]
    ses = read_session(out)
    assert ses.meta.design_alignment == "alignment.xml"
    assert ses.meta.static_s == 10.0 and ses.meta.imu.name == "fog"
    assert ses.imu_t_s.size == summary["imu_samples"]
    assert np.all(np.diff(ses.imu_t_s) > 0) and ses.imu_t_s[1] - ses.imu_t_s[0] == 0.02
    design = read_design(out, ses.meta)
    assert design.start_chainage_m == 0.0
    truth = read_truth_csv(out / "truth.csv")
    assert truth.chainage_m.size == 1201 and truth.chainage_m[-1] == 120.0
    # stops are labelled by the CPIII pair they stand beside: the pair is 2.75 m either side
    cp = {}
    for line in (DEMO / "cpiii.csv").read_text().splitlines()[1:]:
        pid, e, n, h = line.split(",")
        cp[pid] = np.array([float(e), float(n), float(h)])
    assert list(ses.fixes.point) == ["CP0000", "CP0001", "CP0002"]
    for label, enh in zip(ses.fixes.point, ses.fixes.enh_m):
        for side in "LR":
            d = np.hypot(*(cp[label + side][:2] - enh[:2]))
            assert abs(d - 2.75) < 0.02, (label, side, d)
    # same seed, same data
    out2 = tmp_path / "sess2"
    assert _run(["--out", str(out2), "--project", str(DEMO), "--length-m", "120", "--static-s",
                 "10", "--rate-hz", "50", "--seed", "7", "--imu", "fog"]).exit_code == 0
    assert (out / "imu.csv").read_bytes() == (out2 / "imu.csv").read_bytes()


def test_simulate_bad_input_exit_2_and_nothing_written(tmp_path):
    out = tmp_path / "sess"
    r = _run(["--out", str(out), "--project", str(DEMO), "--imu", "laser"])
    assert r.exit_code == 2 and "--imu" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()
    r = _run(["--out", str(out), "--project", str(DEMO), "--length-m", "5000"])
    assert r.exit_code == 2 and "leaves the alignment" in r.stderr
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    r = _run(["--out", str(out), "--project", str(DEMO), "--length-m", "60"])
    assert r.exit_code == 2 and "already exists" in r.stderr
    assert (out / "keep.txt").read_text() == "mine"
    r = _run(["--out", str(out), "--project", str(DEMO), "--length-m", "60", "--force"])
    assert r.exit_code == 2 and "not made by `trolley simulate`" in r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    bad = tmp_path / "proj"
    bad.mkdir()
    (bad / "project.toml").write_text('[simulation]\nlength_m = "long"\n')
    r = _run(["--out", str(tmp_path / "x"), "--project", str(bad)])
    assert r.exit_code == 2 and "simulation.length_m" in r.stderr


def test_demo_cpiii_is_what_the_script_makes():
    spec = importlib.util.spec_from_file_location("make_demo_cpiii",
                                                  REPO / "examples" / "make_demo_cpiii.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    from trolley.landxml import parse_landxml

    a = parse_landxml((DEMO / "alignment.xml").read_text(encoding="utf-8"))
    rows = mod.cpiii_rows(a)
    assert (DEMO / "cpiii.csv").read_text(encoding="utf-8") == "\n".join(rows) + "\n"
    # pairs every 60 m, one each side, 2.75 m from the centre line, 0.3 m above the rail
    from survey.cpiii import parse_cpiii_csv

    pts = parse_cpiii_csv("\n".join(rows), "cpiii.csv")
    assert len(pts) == 2 * (int(a.end_chainage_m // 60) + 1)
    e = np.array([p.e_m for p in pts])
    n = np.array([p.n_m for p in pts])
    proj = a.project(e, n)
    np.testing.assert_allclose(np.abs(proj.lateral_m), 2.75, atol=1e-3)
    np.testing.assert_allclose(proj.chainage_m, np.repeat(60.0 * np.arange(len(pts) // 2), 2),
                               atol=1e-3)
    assert np.all(np.sign(proj.lateral_m) == np.tile([-1.0, 1.0], len(pts) // 2))
