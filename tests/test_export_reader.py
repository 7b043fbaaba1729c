"""What ``trolley export`` reads: which folder holds the track, track.csv parsing (fast and strict
paths agree), the names and equipment figures the Summary sheet shows."""
from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from survey.export import export_outputs
from survey.track_reader import (TRACK_OPTIONAL, TRACK_REQUIRED, ExportInputError, _numeric_columns,
                                 _read_csv_rows, _track_columns_fast, read_track_csv, resolve_track_csv)

HEADER = TRACK_REQUIRED + TRACK_OPTIONAL


def _track(path, n=40, step=0.625):
    """A small straight track.csv (no design: deviations empty)."""
    s = np.arange(n) * step
    lines = [",".join(HEADER)]
    for x in s.tolist():
        lines.append(f"{x!r},{1000 + x!r},5000.0,50.0,0.4,0.5,0.3,,,1435.2,0.0,," + "," * (len(HEADER) - 13))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


SESSION_TOML = """format = "trolley-raw-session/1"
[site]
latitude_deg = 28.0
[trolley]
prism_lever_arm_m = [0.01, -0.02, -0.6]
rail_spacing_m = 1.507
nominal_gauge_m = 1.435
[imu]
gyro_bias_instability_deg_h = 0.03
gyro_arw_deg_sqrt_h = 0.005
accel_bias_ug = 50.0
name = "nav"
[odometer]
scale_noise_per_sqrt_s = 8e-6
[totalstation]
sigma_m = 0.0006
"""


def test_resolve_track_csv_accepts_file_process_and_field_session_folders(tmp_path):
    f = _track(tmp_path / "proc" / "track.csv")
    assert resolve_track_csv(f) == f
    assert resolve_track_csv(tmp_path / "proc") == f
    field = _track(tmp_path / "field" / "processed" / "track.csv")       # survey/session/final.py layout
    assert resolve_track_csv(tmp_path / "field") == field
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "session.toml").write_text(SESSION_TOML, encoding="utf-8")
    (raw / "imu.csv").write_text("t_s,wx_rad_s,wy_rad_s,wz_rad_s,fx_m_s2,fy_m_s2,fz_m_s2\n", encoding="utf-8")
    with pytest.raises(ExportInputError, match=r"raw session folder.*trolley process .*raw --out OUT"):
        resolve_track_csv(raw)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ExportInputError, match="no track.csv"):
        resolve_track_csv(tmp_path / "empty")


def test_cli_export_field_session_folder_and_raw_session_error(tmp_path):
    from typer.testing import CliRunner

    from survey.cli import app

    _track(tmp_path / "field" / "processed" / "track.csv")
    runner = CliRunner()
    r = runner.invoke(app, ["export", str(tmp_path / "field"), "--xlsx", str(tmp_path / "a.xlsx"),
                            "--project", "Line 7", "--session", "night 3"])
    assert r.exit_code == 0, r.stderr
    assert json.loads(r.stdout)["stations"] == 40 and (tmp_path / "a.xlsx").is_file()
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "session.toml").write_text(SESSION_TOML, encoding="utf-8")
    (raw / "imu.csv").write_text("t_s\n", encoding="utf-8")
    r = runner.invoke(app, ["export", str(raw), "--xlsx", str(tmp_path / "b.xlsx")])
    assert r.exit_code == 2 and "trolley process" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "b.xlsx").exists()
    r = runner.invoke(app, ["export", "--help"])
    assert "processed/track.csv" in r.stdout


@settings(max_examples=40, deadline=None)
@given(st.lists(st.lists(st.floats(allow_nan=False, allow_infinity=False, width=64),
                         min_size=len(HEADER) - 1, max_size=len(HEADER) - 1), min_size=1, max_size=30),
       st.lists(st.booleans(), min_size=len(TRACK_OPTIONAL), max_size=len(TRACK_OPTIONAL)))
def test_fast_reader_equals_strict_reader(tmp_path_factory, rows, empty_optional):
    """pandas' C reader gives exactly the floats of the strict cell-by-cell reader."""
    path = tmp_path_factory.mktemp("fast") / "track.csv"
    lines = [",".join(HEADER)]
    for i, r in enumerate(rows):
        cells = [repr(float(i))] + [repr(v) for v in r]
        cells = [("" if (k >= len(TRACK_REQUIRED) and empty_optional[k - len(TRACK_REQUIRED)]) else c)
                 for k, c in enumerate(cells)]
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    fast = _track_columns_fast(path)
    assert fast is not None
    header, body = _read_csv_rows(path)
    strict = _numeric_columns(path, header, body, HEADER, set(TRACK_OPTIONAL))
    assert fast.keys() == strict.keys()
    for k in strict:
        np.testing.assert_array_equal(fast[k], strict[k], err_msg=k)


def test_unusual_file_takes_strict_path_with_same_result(tmp_path):
    clean = _track(tmp_path / "a" / "track.csv")
    text = clean.read_text(encoding="utf-8").splitlines()
    odd = [text[0], text[1], "   ", text[2].replace(",,,", ",nan, NaN ,", 1)] + text[3:]  # blank line, nan text
    p = tmp_path / "b" / "track.csv"
    p.parent.mkdir()
    p.write_text("\n".join(odd) + "\n", encoding="utf-8")
    assert _track_columns_fast(p) is None
    a, _ = read_track_csv(clean)
    b, _ = read_track_csv(p)
    for k in ("chainage_m", "E_m", "gauge_m", "cant_m", "lateral_dev_m"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    bad = tmp_path / "c.csv"
    bad.write_text("\n".join(text[:3] + [text[3].replace("1435.2", "abc")]) + "\n", encoding="utf-8")
    with pytest.raises(ExportInputError, match="row 4, column gauge_mm: .abc. is not a number"):
        read_track_csv(bad)
    # numpy (the strict path's column parser) reads a full-width digit as its ASCII twin: refused like the rest
    bad.write_text("\n".join(text[:3] + [text[3].replace("1435.2", "1\uff1435.2")]) + "\n", encoding="utf-8")
    with pytest.raises(ExportInputError, match="row 4, column gauge_mm: '1\uff1435.2' is not a number: "
                                               "'\uff14' \\(U\\+FF14 FULLWIDTH DIGIT FOUR\\) is not ASCII"):
        read_track_csv(bad)


def test_a_row_cut_short_is_refused_on_both_paths(tmp_path):
    # a file copied while it was written ends in half a row; its missing cells must not read as
    # "not measured" (review of 2026-11-26: such a track.csv exported as PASS)
    clean = _track(tmp_path / "a" / "track.csv")
    text = clean.read_text(encoding="utf-8")
    cut = tmp_path / "cut.csv"
    cut.write_text(text[: text.rindex(",1435.2,")], encoding="utf-8")
    mid = tmp_path / "mid.csv"
    lines = text.splitlines()
    mid.write_text("\n".join(lines[:10] + [",".join(lines[10].split(",")[:7])] + lines[11:]) + "\n", encoding="utf-8")
    assert len(lines[1].split(",")) == len(HEADER)
    for path, row, cells in ((cut, 41, 9), (mid, 11, 7)):
        assert _track_columns_fast(path) is None
        with pytest.raises(ExportInputError, match=f"row {row}: {cells} cells, the header has {len(HEADER)} columns .a truncated"):
            read_track_csv(path)


def test_a_misspelled_optional_column_and_a_missing_gauge_are_said(tmp_path):
    from typer.testing import CliRunner

    from survey.cli import app
    from survey.track_reader import read_track_file

    clean = _track(tmp_path / "a" / "track.csv")
    odd = tmp_path / "b" / "track.csv"
    odd.parent.mkdir()
    odd.write_text(clean.read_text(encoding="utf-8").replace("gauge_mm", "gauge", 1), encoding="utf-8")
    assert read_track_file(clean).notes == []
    notes = read_track_file(odd).notes
    assert notes == ["track.csv column 'gauge' is not a track.csv column and was ignored (meant gauge_mm?)"]
    r = CliRunner().invoke(app, ["export", str(odd), "--xlsx", str(tmp_path / "b.xlsx")])
    assert r.exit_code == 0, r.stderr
    assert "meant gauge_mm?" in r.stderr and "has no gauge_mm: its tolerances are not checked" in r.stderr
    assert "track.csv has no gauge_mm: its tolerances are not checked" in json.loads(r.stdout)["notes"]
    r = CliRunner().invoke(app, ["export", str(clean), "--xlsx", str(tmp_path / "a.xlsx")])
    assert r.exit_code == 0 and "note:" not in r.stderr


def test_a_gap_in_the_track_is_empty_in_the_sheet_and_said(tmp_path):
    # 40 stations with 10 of them missing (6.25-11.875 m): the sheet and the CSV keep the grid,
    # but its stations inside the gap are empty, not a straight line; the notes name the gap
    from openpyxl import load_workbook
    from typer.testing import CliRunner

    from survey.cli import app

    path = _track(tmp_path / "t" / "track.csv")
    lines = path.read_text(encoding="utf-8").splitlines()
    path.write_text("\n".join(lines[:11] + lines[21:]) + "\n", encoding="utf-8")   # stations 6.25 m .. 11.875 m out
    r = CliRunner().invoke(app, ["export", str(path), "--xlsx", str(tmp_path / "g.xlsx"), "--csv",
                                 str(tmp_path / "g.csv")])
    assert r.exit_code == 0, r.stderr
    note = "track.csv has no stations in 5.625-12.500 m (longer than 2 steps of 0.625 m)"
    assert any(n.startswith(note) for n in json.loads(r.stdout)["notes"]) and note in r.stderr
    rows = [line.split(",") for line in (tmp_path / "g.csv").read_text(encoding="utf-8").splitlines()[1:]]
    head = (tmp_path / "g.csv").read_text(encoding="utf-8").splitlines()[0].split(",")
    assert len(rows) == 40
    for row in rows:
        s, gauge = float(row[0]), row[head.index("gauge_mm")]
        assert (gauge == "") == (5.625 < s < 12.5), (s, gauge)
    wb = load_workbook(tmp_path / "g.xlsx")
    texts = [str(r[1].value) for r in wb["Summary"].iter_rows(min_row=1, max_col=2)]
    assert any("no stations in 1 gap(s), left empty: 5.625-12.500 m" in t for t in texts)


def test_a_value_shown_at_the_limit_is_not_a_defect(tmp_path):
    # gauge 1436.00004 mm is kept in the files as 1.0000 mm of gauge deviation, at the 1 mm limit:
    # not a defect; 1436.0002 (kept as 1.0002) is, with that peak; the stats agree
    path = _track(tmp_path / "t" / "track.csv", n=161)
    lines = path.read_text(encoding="utf-8").splitlines()
    for k, gauge in ((41, "1436.00004"), (101, "1433.99996"), (121, "1436.0002")):
        lines[k] = lines[k].replace(",1435.2,", f",{gauge},")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    res = export_outputs(path, tmp_path / "r.xlsx", None, None)
    gauge = [d for d in res.report.defects if d.parameter == "gauge_dev"]
    assert [(d.start_chainage_m, d.peak) for d in gauge] == [(75.0, pytest.approx(0.0010002, abs=1e-13))]
    assert res.report.stats["gauge_dev_m"].maximum == pytest.approx(0.0010002, abs=1e-13)
    assert res.report.stats["gauge_dev_m"].minimum == pytest.approx(-0.001, abs=1e-15)


def test_a_single_station_is_refused_naming_the_file(tmp_path):
    from survey.track_reader import read_track_file

    path = _track(tmp_path / "track.csv", n=1)
    with pytest.raises(ExportInputError, match=r"track.csv: 1 station; a track needs at least two"):
        read_track_file(path)


def _summary(wb) -> dict:
    return {r[0].value: r[1].value for r in wb["Summary"].iter_rows(min_row=1, max_col=2) if r[0].value}


def test_summary_names_and_equipment_from_session_toml(tmp_path):
    """summary.json without equipment: the figures come from its session's session.toml;
    explicit names win over summary.json's."""
    from openpyxl import load_workbook

    out = tmp_path / "out"
    _track(out / "processed" / "track.csv")
    sess = out / "session"
    sess.mkdir()
    (sess / "session.toml").write_text(SESSION_TOML, encoding="utf-8")
    (out / "processed" / "summary.json").write_text(json.dumps({
        "session_dir": str(sess), "project": "", "session": "session", "rail_spacing_m": 1.507}))
    res = export_outputs(out, tmp_path / "s.xlsx", None, tmp_path / "plots", project_name="Line 7",
                         session_name="=night 3")
    s = _summary(load_workbook(tmp_path / "s.xlsx"))
    assert s["Project"] == "Line 7" and s["Session"] == "=night 3"
    assert s["IMU"] == "nav"
    assert s["Gyro bias instability [deg/h]"] == pytest.approx(0.03, rel=1e-12)
    assert s["Gyro ARW [deg/sqrt(h)]"] == 0.005 and s["Total-station sigma [mm]"] == 0.6   # no 0.6000000000000001
    assert s["Accelerometer bias [µg]"] == pytest.approx(50.0, rel=1e-12)
    assert s["Odometer scale noise [1/sqrt(s)]"] == pytest.approx(8e-6, rel=1e-12)
    assert s["Total-station sigma [mm]"] == pytest.approx(0.6, rel=1e-12)
    assert s["Prism lever arm x, y, z (FRD) [m]"] == "0.010, -0.020, -0.600"
    assert s["Rail spacing [m]"] == pytest.approx(1.507) and s["Nominal gauge [mm]"] == pytest.approx(1435.0)
    assert s["Equipment figures from"].endswith("session.toml")
    assert all(p.is_file() for p in res.plots) and len(res.plots) >= 2


def test_summary_dict_names_and_equipment_reach_the_sheet(tmp_path):
    """trackio.summary_dict records the names it is given (no parent-folder guess) and every
    equipment figure; the export shows them from summary.json."""
    from openpyxl import load_workbook

    from survey.sessionio import _parse_meta
    from survey.trackio import summary_dict
    session = SimpleNamespace(meta=_parse_meta(SESSION_TOML))     # summary_dict reads only .meta
    result = SimpleNamespace(
        summary={"fixes_used": 3, "fixes_rejected": 1, "longest_rejected_run": 1, "fixes_readmitted": 0,
                 "fixes_snooped_out": 0, "rms_innovation_m": 3e-4, "max_sigma_m": 6e-4,
                 "heading_source": "gyrocompassing", "initial_heading_deg": 10.0, "heading_sigma_deg": 0.1},
        config=SimpleNamespace(smoother="rts", step_m=0.625), observability_ranks=None, node_count=10,
        stations=SimpleNamespace(chainage_m=np.zeros(40)))
    d = summary_dict(result, session, tmp_path / "out" / "session")
    assert d["project"] == "" and d["session"] == "session"
    d = summary_dict(result, session, tmp_path / "out" / "session", project_name="Line 7", session_name="night 3")
    assert d["project"] == "Line 7" and d["session"] == "night 3"
    eq = d["equipment"]
    assert eq["accel_bias_ug"] == pytest.approx(50.0) and eq["totalstation_sigma_mm"] == pytest.approx(0.6)
    assert eq["prism_lever_arm_m"] == [0.01, -0.02, -0.6] and eq["nominal_gauge_mm"] == pytest.approx(1435.0)
    out = tmp_path / "proc"
    _track(out / "track.csv")
    (out / "summary.json").write_text(json.dumps(d), encoding="utf-8")
    export_outputs(out, tmp_path / "s.xlsx", None, None)
    s = _summary(load_workbook(tmp_path / "s.xlsx"))
    assert s["Project"] == "Line 7" and s["Session"] == "night 3"
    assert s["Odometer scale noise [1/sqrt(s)]"] == pytest.approx(8e-6)
    assert s["Equipment figures from"].endswith("summary.json (equipment)")
    assert s["Fixes rejected"] == 1 and math.isclose(s["RMS innovation [mm]"], 0.3)


def test_summary_json_bad_equipment_is_a_clear_error(tmp_path):
    out = tmp_path / "proc"
    _track(out / "track.csv")
    (out / "summary.json").write_text(json.dumps({"equipment": {"accel_bias_ug": "fifty"}}), encoding="utf-8")
    with pytest.raises(ExportInputError, match=r"summary.json: key equipment.accel_bias_ug: expected a number"):
        export_outputs(out, tmp_path / "s.xlsx", None, None)
    assert not (tmp_path / "s.xlsx").exists()


def _excel_text(value: float, fmt: str) -> str:
    """What Excel shows for ``value`` in a number format ``0.00`` / ``0.00##`` (decimals: the
    zeros always, the hashes where not zero)."""
    decimals = fmt.rpartition(".")[2]
    fixed, optional = decimals.count("0"), decimals.count("#")
    text = f"{value:.{fixed + optional}f}"
    return text[:len(text) - optional] + text[len(text) - optional:].rstrip("0")


def test_a_red_value_never_reads_as_its_limit_on_the_sheet(tmp_path):
    # gauge dev against max_abs 1 mm, the sheet showing mm to 2 decimals: exactly 1.00 (at the
    # limit: not red), 1.004 and -1.004 (beyond by less than half the last digit: red, and shown
    # with the digits they are checked on, not as "1.00"), 1.5 (clearly beyond: red, "1.50").
    # The red cells are as many as the Summary's stations beyond, whose min and limits read the same way.
    import re

    from openpyxl import load_workbook

    from track_sheet import track_table

    path = _track(tmp_path / "t" / "track.csv", n=40)
    lines = path.read_text(encoding="utf-8").splitlines()
    for k, gauge in ((11, "1436.0"), (21, "1436.004"), (26, "1433.996"), (31, "1436.5")):
        lines[k] = lines[k].replace(",1435.2,", f",{gauge},")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    tol = tmp_path / "tol.toml"
    tol.write_text('format = "trolley-tolerances/1"\nname = "g"\ntitle = "G"\ndescription = "d"\n'
                   '[limits.gauge_dev]\nmax_abs_mm = 1.0\nsource = "test"\n', encoding="utf-8")
    res = export_outputs(path, tmp_path / "g.xlsx", None, None, tolerances=str(tol))
    wb = load_workbook(tmp_path / "g.xlsx")
    ws = wb["Track"]
    head_row, heads = track_table(ws)
    j = heads.index("Gauge dev [mm] (nominal 1435)") + 1
    (rule,) = [r.rules[0].formula[0] for r in ws.conditional_formatting]
    lo, hi = (float(x) for x in re.search(r"<(-?[\d.]+),\w+\d+>(-?[\d.]+)\)", rule).groups())
    cells = {k: ws.cell(head_row + 1 + k, j) for k in (10, 20, 25, 30, 5)}   # station k
    shown = {k: (c.value, lo <= c.value <= hi, _excel_text(c.value, c.number_format)) for k, c in cells.items()}
    assert shown == {10: (1.0, True, "1.00"), 20: (1.004, False, "1.004"), 25: (-1.004, False, "-1.004"),
                     30: (1.5, False, "1.50"), 5: (pytest.approx(0.2), True, "0.20")}
    red = sum(1 for (c,) in ws.iter_rows(min_row=head_row + 1, min_col=j, max_col=j)
              if c.value is not None and not lo <= c.value <= hi)
    summary = {r[0].value: r for r in wb["Summary"].iter_rows(min_row=1, max_col=13) if r[0].value}
    row = summary["Gauge dev [mm] (nominal 1435)"]
    assert red == 3 == row[10].value == sum(d.stations for d in res.report.defects)
    # min -1.004 beside a lower limit shown "-1.00"; max 1.5 is far enough to keep 2 decimals
    assert [_excel_text(c.value, c.number_format) for c in row[5:7] + row[8:10]] == ["-1.004", "1.50", "-1.00", "1.00"]


def test_the_pdf_and_the_limits_read_as_the_sheet():
    # the PDF's statistics use SheetColumn.text: a value just beyond its limit gets the checked
    # digits; a limit of 1/1500 mm/m written 0.6667 is shown so, not "0.667"; a limit converted
    # to SI and back is the value the file wrote (18 mm was 18.000000000000004: a value of
    # exactly 18 would have been red or not depending on the last bit)
    from survey.track_table import limit_in_column, limit_text, sheet_columns
    from trolley.tolerances import Limit
    from trolley.trackgeometry import GeometryConfig

    cols = {c.key: c for c in sheet_columns(GeometryConfig())}
    gauge, twist_rate = cols["gauge_dev_m"], cols["twist_rate_m_per_m"]
    assert [gauge.text(v, -1.0, 1.0) for v in (1.0, 1.004, -1.005, 1.006, 0.3)] == \
        ["1.00", "1.004", "-1.005", "1.01", "0.30"]
    assert twist_rate.text(0.6668, -0.6667, 0.6667) == "0.6668" and twist_rate.close_format == "0.000##"
    assert limit_text(0.6667, 3, 5) == "0.6667" and limit_text(1.0, 2, 4) == "1.00" and limit_text(np.inf, 2, 4) == ""
    for mm in (18.0, 0.2443, 0.9):
        lim = Limit("gauge_dev", "gauge_dev_m", -mm * 1e-3, mm * 1e-3, "mm", source="t")
        assert limit_in_column(lim, gauge) == (-mm, mm)


def test_an_export_that_asks_for_no_output_is_refused_unless_it_is_a_check(tmp_path):
    # `trolley export DIR` alone computed everything, wrote nothing and exited 0: a forgotten
    # --xlsx looked like a success
    from typer.testing import CliRunner

    from survey.cli import app

    path = _track(tmp_path / "t" / "track.csv")
    before = sorted(tmp_path.rglob("*"))
    r = CliRunner().invoke(app, ["export", str(path)])
    assert r.exit_code == 2 and r.stdout == ""
    assert r.stderr == ("error: nothing to write: give one or more of --xlsx FILE, --pdf FILE, --csv FILE, "
                        "--plots FOLDER (or --fail-on-defects or --json to check the track without writing a "
                        "file)\n"), r.stderr
    # the check is the purpose of --fail-on-defects (and of --json): it goes on and says that
    # nothing was written
    for check in ("--fail-on-defects", "--json"):
        r = CliRunner().invoke(app, ["export", str(path), check])
        assert r.exit_code == 0, r.stderr
        assert json.loads(r.stdout)["stations"] == 40 and json.loads(r.stdout)["passed"] is True
        assert "note: no output file asked for (--xlsx, --pdf, --csv, --plots): nothing written" in r.stderr
    assert sorted(tmp_path.rglob("*")) == before
    # with an output there is no such note
    r = CliRunner().invoke(app, ["export", str(path), "--csv", str(tmp_path / "t.csv")])
    assert r.exit_code == 0 and "nothing written" not in r.stderr and (tmp_path / "t.csv").is_file()
