"""The field record (survey/fieldrecord.py) and what the sheet makes of it: rejected and undone
fixes with their reason, the overlap checks with their verdict, the station setups with their
residuals, the survey header set with `trolley project set`."""
from __future__ import annotations

import json

import numpy as np
import pytest

from test_export_workbook import _write_outputs


def _store(tmp_path):
    """A project whose session has two station setups, an overlap check outside the tolerance
    (FIX003, as FIX013 of the demo), a fix the crew undid and one re-measured."""
    from survey.store import FixRecord, ProjectStore, SetupObservation, StationSetupRecord

    st = ProjectStore.create(tmp_path / "projects", "p1")
    sid = st.create_session("s1").session_id
    ids = []
    for k, e in enumerate((1000.0, 1060.0)):
        setup = StationSetupRecord(t_s=10.0 + 100 * k, station_enh_m=np.array([e, 5000.0, 50.0]), orientation_rad=0.5,
                                   covariance=np.eye(4) * 1e-8, sigma0=0.9, dof=5, excluded=("CP9",) if k else ())
        obs = [SetupObservation("CP1", 0.1, 1.5, 30.0, True, 1e-6, 2e-6, 3e-4, 1e-4, -2e-4, 5e-4, 0.8, False, ""),
               SetupObservation("CP2", 0.2, 1.5, 40.0, True, 1e-6, 2e-6, 3e-4, 1e-4, -2e-4, 5e-4, 3.9, True,
                                "|w| 3.9 > 3.29")]
        if k:
            obs.append(SetupObservation("CP9", 0.3, 1.5, 50.0, used=False, reason="excluded by the crew"))
        ids.append(st.add_station_setup(sid, setup, obs))
    P = [1000.0, 5000.0, 50.0]
    fixes = [FixRecord(20.0, "FIX001", *P, 6e-4, 6e-4, 6e-4, setup_id=ids[0]),
             FixRecord(80.0, "FIX002", 1060.0, 5000.0, 50.0, 6e-4, 6e-4, 6e-4, setup_id=ids[0]),
             # overlap: the same stop from station 2, 3 mm higher: outside the 2 mm tolerance
             FixRecord(120.0, "FIX003", 1060.0005, 5000.0, 50.003, 6e-4, 6e-4, 6e-4, setup_id=ids[1], accepted=False,
                       reason="overlap check from station 2: difference outside the tolerance"),
             FixRecord(180.0, "FIX004", 1120.0, 5000.0, 50.0, 6e-4, 6e-4, 6e-4, setup_id=ids[1]),
             FixRecord(240.0, "FIX005", 1180.0, 5000.0, 50.0, 6e-4, 6e-4, 6e-4, setup_id=ids[1], accepted=False,
                       reason="rejected: measured again")]
    fix_ids = [st.add_fix(sid, f) for f in fixes]
    st.decide_fix(fix_ids[3], False, "undone by the crew")
    st.set_header("line", "4711 Hannover-Würzburg")
    st.set_header("totalstation_serial", "884512")
    st.set_header("totalstation_calibrated", "2026-03-14")
    return st


def test_field_record_round_trip_and_overlap_difference(tmp_path):
    from survey.fieldrecord import field_record, read_field_record, record_json, write_field_record

    with _store(tmp_path) as st:
        rec = field_record(st, "s1")
    assert [(f.point, f.reason) for f in rec.rejected] == [
        ("FIX003", "overlap check from station 2: difference outside the tolerance"),
        ("FIX004", "undone by the crew"), ("FIX005", "rejected: measured again")]
    (o,) = rec.overlaps
    assert (o.old_point, o.new_point, o.from_station, o.to_station) == ("FIX002", "FIX003", 1, 2)
    assert (o.dE_m, o.dN_m, o.dH_m) == pytest.approx((0.0005, 0.0, 0.003), abs=1e-9) and not o.within
    # the difference's sigma from the two fixes' stored sigmas (0.6 mm each): sqrt(0.72) = 0.849 mm per
    # axis, and 3 mm in H is 3.54 of them; jointly (correlations from the setups) beyond 3.44
    assert (o.sigma_dE_m, o.sigma_dN_m, o.sigma_dH_m) == pytest.approx((np.sqrt(0.72e-6),) * 3, rel=1e-12)
    assert o.max_d_over_sigma == pytest.approx(3.0 / np.sqrt(0.72), rel=1e-6)
    assert o.consistent is False and o.sigma_limit == pytest.approx(3.436, abs=1e-3)
    assert o.mahalanobis > o.sigma_limit and o.sigma_verdict == f"BEYOND 3.44 joint sigma ({o.mahalanobis:.2f})"
    assert [s.excluded for s in rec.setups] == [(), ("CP9",)] and rec.header["line"] == "4711 Hannover-Würzburg"
    assert rec.start_utc <= rec.end_utc and rec.start_utc
    path = write_field_record(tmp_path, rec)
    back = read_field_record(path)
    assert record_json(back) == record_json(rec) and back.fixes == rec.fixes and back.overlaps == rec.overlaps
    assert np.isnan(back.setups[1].pointings[2].across_m)
    doc = json.loads(path.read_text(encoding="utf-8"))
    assert doc["format"] == "trolley-field-record/1"
    assert doc["setups"][1]["pointings"][2]["across_m"] is None     # NaN written as null, valid JSON
    assert doc["overlaps"][0]["consistent"] is False and doc["fixes"][0]["sigma_H_m"] == 6e-4
    # a record written before the sigmas were kept still reads: no sigma, no statistical verdict
    for f in doc["fixes"]:
        for k in ("sigma_E_m", "sigma_N_m", "sigma_H_m"):
            del f[k]
    for k in ("sigma_dE_m", "sigma_dN_m", "sigma_dH_m", "max_d_over_sigma", "sigma_limit", "consistent"):
        del doc["overlaps"][0][k]
    path.write_text(json.dumps(doc), encoding="utf-8")
    old = read_field_record(path)
    assert np.isnan(old.fixes[0].sigma_H_m) and old.overlaps[0].consistent is None
    assert np.isnan(old.overlaps[0].sigma_dH_m) and old.overlaps[0].dH_m == pytest.approx(0.003, abs=1e-9)


def test_overlap_checks_from_the_fixes_sigmas():
    # 0.8 mm per axis on both fixes: the difference has sigma 1.131 mm, and H +2.19 mm is 1.94 of them:
    # outside the 2 mm tolerance, within 3 sigma; fixes stored without sigmas give no statistical verdict
    from survey.fieldrecord import RecordFix, overlap_checks

    s = (8e-4,) * 3
    fixes = [RecordFix(1.0, "FIX001", 10.0, 20.0, 30.0, 1, True, "accepted", *s),
             RecordFix(2.0, "FIX002", 10.0, 20.0, 30.00219, 2, True, "overlap check from station 2: accepted", *s)]
    (o,) = overlap_checks(fixes, 0.002)
    assert not o.within and o.consistent is True
    assert o.sigma_dH_m == pytest.approx(np.sqrt(2) * 8e-4, rel=1e-12)
    assert o.max_d_over_sigma == pytest.approx(2.19 / (np.sqrt(2) * 0.8), rel=1e-6)
    bare = [RecordFix(f.t_s, f.point, f.E_m, f.N_m, f.H_m, f.station, f.accepted, f.reason) for f in fixes]
    (o,) = overlap_checks(bare, 0.002)
    assert not o.within and o.consistent is None and np.isnan(o.sigma_dH_m)


def test_sheet_lists_rejected_fixes_overlaps_setups_and_header(tmp_path):
    from openpyxl import load_workbook

    from survey.export import export_outputs
    from survey.fieldrecord import field_record, write_field_record
    from survey.workbook import HEADER_ROWS, TABLE_ROW

    out = _write_outputs(tmp_path / "o")
    with _store(tmp_path) as st:
        write_field_record(out, field_record(st, "s1"))
    export_outputs(out, tmp_path / "s.xlsx", None, None)
    wb = load_workbook(tmp_path / "s.xlsx")
    fx = wb["Fixes"]
    rows = {r[1]: r for r in fx.iter_rows(min_row=TABLE_ROW + 1, values_only=True) if r[1]}
    # fixes.csv of the processing has CP1, ...; the field session's rejections are added with their reason
    assert rows["FIX003"][9] == "no" and rows["FIX003"][10] == "overlap check from station 2: difference outside the tolerance"
    assert rows["FIX003"][11] == 2 and rows["FIX003"][12] == "field session / crew"
    assert rows["FIX004"][10] == "undone by the crew" and rows["FIX005"][10] == "rejected: measured again"
    assert rows["-12"][10] == "@NIS 40.0 > 11.3"                    # the filter's own rejection stays
    summary = {r[0].value: r[1].value for r in wb["Summary"].iter_rows(min_row=1, max_col=2)}
    assert summary["Fixes rejected by the filter"] == 1
    assert summary["Fixes rejected or undone in the field"] == 3 and summary["Fixes rejected"] == 4
    assert summary["Overlap checks"].startswith("1 (1 outside the tolerance: FIX003)")
    assert summary["Line"] == "4711 Hannover-Würzburg" and summary["Total station serial number"] == "884512"
    assert summary["Total station calibrated"] == "2026-03-14" and summary["Track"] == "not given"
    assert summary["Project"] == "p1" and summary["Session"] == "s1"   # the field record's names
    lines = [wb["Defects"].cell(r, 1).value for r in range(2, HEADER_ROWS + 1)]
    assert "Line: 4711 Hannover-Würzburg" in lines[0] and "serial 884512, calibrated 2026-03-14" in lines[2]
    fs = [[c for c in r] for r in wb["Free stations"].iter_rows(min_row=TABLE_ROW, values_only=True)]
    text = [r[0] for r in fs if r[0]]
    assert any(t.startswith("Station 2:") and "dropped: CP9" in t for t in text)
    flagged = [r for r in fs if r[0] == "CP2"]
    assert len(flagged) == 2 and flagged[0][9] == "|w| 3.9 > 3.29" and flagged[0][8] == pytest.approx(3.9)
    (ov,) = [r for r in fs if r[0] == "FIX002"]
    assert ov[1] == "FIX003" and ov[7] == "OUTSIDE" and ov[5] == pytest.approx(3.0) and ov[6] == pytest.approx(2.0)
    # its sigma per axis, the largest |d| / sigma and the verdict against 3 sigma
    assert ov[10:13] == pytest.approx((np.sqrt(0.72),) * 3, rel=1e-12)
    assert ov[13] == pytest.approx(3.0 / np.sqrt(0.72), rel=1e-6) and ov[14].startswith("BEYOND 3.44 joint sigma (")


def test_project_set_validates_and_show_lists(tmp_path):
    from typer.testing import CliRunner

    from survey.cli import app

    runner = CliRunner()
    root = str(tmp_path / "projects")
    assert runner.invoke(app, ["project", "new", "p", "--root", root, "--no-toml"]).exit_code == 0
    r = runner.invoke(app, ["project", "set", "imu_serial", "RQH-2231", "--project", "p", "--root", root])
    assert r.exit_code == 0, r.output
    for key, value, msg in (("bogus", "x", "unknown key 'bogus'; the keys are: line, track"),
                            ("imu_calibrated", "14.03.2026", "not a date as YYYY-MM-DD"),
                            ("rail_temperature_c", "hot", "not a temperature"),
                            ("rail_temperature_c", "150", "error: rail_temperature_c: must be <= 90, got 150 (°C)"),
                            ("rail_temperature_c", "-60.5",
                             "error: rail_temperature_c: must be >= -60, got -60.5 (°C)"),
                            # the finite-number message of every number on the command line
                            *(("rail_temperature_c", v, f"error: rail_temperature_c: must be a finite number, got {v}")
                              for v in ("nan", "inf", "-inf")),
                            ("rail_temperature_c", "1_0", "not a temperature"),
                            ("crew", "a\nb", "control characters")):
        r = runner.invoke(app, ["project", "set", key, value, "--project", "p", "--root", root])
        assert r.exit_code == 2 and msg in r.output, (key, r.output)
    # a winter reading: "-5" is the value, not an option
    r = runner.invoke(app, ["project", "set", "rail_temperature_c", "-5", "--project", "p", "--root", root])
    assert r.exit_code == 0 and "Rail temperature [°C]: -5" in r.output, r.output
    r = runner.invoke(app, ["project", "show", "p", "--root", root, "--json"])
    assert json.loads(r.stdout)["header"] == {"imu_serial": "RQH-2231", "rail_temperature_c": "-5"}
    assert runner.invoke(app, ["project", "set", "rail_temperature_c", "", "--project", "p", "--root", root]).exit_code == 0
    assert runner.invoke(app, ["project", "set", "imu_serial", "", "--project", "p", "--root", root]).exit_code == 0
    r = runner.invoke(app, ["project", "show", "p", "--root", root, "--json"])
    assert json.loads(r.stdout)["header"] == {}
    # the help lists every key the store accepts
    from survey.surveyheader import HEADER_FIELDS

    helptext = " ".join(runner.invoke(app, ["project", "set", "--help"], terminal_width=80).output.split())
    assert all(k in helptext for k in HEADER_FIELDS)
