"""The survey workbook, CSV, plots and the ``trolley export`` command on a synthetic survey."""
from __future__ import annotations

import csv
import json
import shutil
import subprocess

import numpy as np
import pytest

from survey.export import export_outputs
from survey.plots import km_label
from survey.workbook import HEADER_ROWS, TABLE_ROW, TRACK_FIRST_ROW
from track_sheet import track_table
from trolley.alignment import Alignment, Arc, CantProfile, Clothoid, HorizontalAlignment, Line, VerticalProfile

STEP = 0.625
N = 800                                  # 500 m
HOSTILE = '=HYPERLINK("http://x","y")'


def _write_outputs(out, with_design=True, with_fixes=True, with_summary=True):
    """A processing output folder: track.csv, fixes.csv, summary.json, session with LandXML."""
    import pandas as pd
    from trolley.landxml import landxml_text

    out.mkdir(parents=True, exist_ok=True)
    hz = HorizontalAlignment.from_elements(1000.0, 5000.0, 0.3, [
        Line(100.0), Clothoid(50.0, 0.0, 1 / 1200), Arc(200.0, 1 / 1200), Clothoid(50.0, 1 / 1200, 0.0), Line(150.0)])
    prof = VerticalProfile.from_pvis([0.0, 250.0, 550.0], [50.0, 52.0, 51.0], [0.0, 200.0, 0.0])
    cant = CantProfile.from_stations([100.0, 150.0, 350.0, 400.0], [0.0, 0.08, 0.08, 0.0])
    al = Alignment(hz, prof, cant, name="main")
    sess = out / "session"
    sess.mkdir(exist_ok=True)
    if with_design:
        (sess / "alignment.xml").write_text(landxml_text(al), encoding="utf-8")
        (sess / "session.toml").write_text('format = "trolley-raw-session/1"\n[design]\nalignment = "alignment.xml"\n')
    s = np.arange(N) * STEP
    d = al.evaluate(s)
    rng = np.random.default_rng(3)
    lat = 0.0004 * np.sin(2 * np.pi * s / 17.0) + rng.normal(0, 5e-5, N)
    lat[(s >= 200.0) & (s <= 203.0)] += 0.006          # a 6 mm lateral kink: defects
    vert = 0.0003 * np.sin(2 * np.pi * s / 13.0 + 1.0)
    E = d.E_m + lat * np.cos(d.heading_rad)
    Nn = d.N_m - lat * np.sin(d.heading_rad)
    cant_m = 1.5 * np.sin(d.cant_rad)
    gauge = np.full(N, 1.4352)
    gauge[(s > 420) & (s < 421)] = 1.4375                 # +2.5 mm gauge: a defect
    pd.DataFrame({"chainage_m": s, "E_m": E, "N_m": Nn, "H_m": d.H_m + vert, "sigma_E_mm": 0.4,
                  "sigma_N_mm": 0.5, "sigma_H_mm": 0.3, "lateral_dev_mm": lat * 1e3,
                  "vertical_dev_mm": vert * 1e3, "gauge_mm": gauge * 1e3, "cant_mm": cant_m * 1e3,
                  "twist_mm": np.nan}).to_csv(out / "track.csv", index=False, float_format="%.6f", na_rep="")
    if with_fixes:
        pd.DataFrame({"t_s": [0.0, 60.0, 120.0, 180.0], "point": ["CP1", HOSTILE, "-12", "CP\x014"],
                      "E_m": 1000.0, "N_m": 5000.0, "H_m": 50.0, "innov_E_mm": [0.1, 0.2, 5.0, -0.1],
                      "innov_N_mm": 0.1, "innov_H_mm": -0.2, "nis": [1.0, 2.0, 40.0, 0.5],
                      "accepted": [1, 1, 0, 1], "reason": ["", "", "@NIS 40.0 > 11.3", ""]}
                     ).to_csv(out / "fixes.csv", index=False)
    if with_summary:
        (out / "summary.json").write_text(json.dumps({
            "session_dir": str(sess), "project": "=1+1", "session": "S1",
            "imu": {"name": "nav-grade", "gyro_bias_instability_deg_h": 0.01, "gyro_arw_deg_sqrt_h": 0.003},
            "smoother": "rts", "fixes_used": 3, "fixes_rejected": 1, "rms_innovation_mm": 0.3,
            "max_sigma_mm": 0.6, "step_m": STEP, "rail_spacing_m": 1.5, "nominal_gauge_m": 1.435}))
    return out


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    base = tmp_path_factory.mktemp("export")
    out = _write_outputs(base / "out")
    res = export_outputs(out, base / "survey.xlsx", base / "track_table.csv", base / "plots")
    return base, res


def test_workbook_structure(exported):
    from openpyxl import load_workbook

    base, res = exported
    wb = load_workbook(base / "survey.xlsx")
    assert wb.sheetnames == ["Summary", "Track", "Track print", "Defects", "Fixes", "Free stations", "Notes", "Charts",
                             "ChartData"]
    assert wb["ChartData"].sheet_state == "hidden"
    ws = wb["Track"]
    head, heads = track_table(ws)
    first = head + 1                                         # the first station row
    # the header block above the table, right of the chainage and station columns (repeated on every page)
    assert head > HEADER_ROWS and ws.cell(2, 3).value.startswith("Project: ") and ws.cell(2, 1).value is None
    assert heads[:3] == ["Chainage [m]", "Station [km+m]", "E [m]"]
    assert "Lateral dev [mm] +right" in heads and "Twist 3 m [mm] +left high" in heads
    assert "Alignment D1 3-25 m [mm] +right" in heads and "Chord 300/150 m vert [mm] +up" in heads
    assert "Versine H 10 m [mm] centre-chord +right" in heads and "Level 10 m chord [mm] centre-chord +up" in heads
    last = head + N                                          # the last station row
    assert ws.max_row == last and ws.freeze_panes == f"C{first}"
    assert ws.auto_filter.ref == f"A{head}:{ws.cell(1, len(heads)).column_letter}{last}"
    # number formats and values of one row against the computed geometry
    row = first + 399
    g = res.report.geometry
    assert ws.cell(row, 1).value == pytest.approx(g.chainage_m[row - first])
    assert ws.cell(row, 2).number_format == '0"+"000.000'
    j = heads.index("Lateral dev [mm] +right") + 1
    assert ws.cell(row, j).number_format == "0.00"
    assert ws.cell(row, j).value == pytest.approx(g.columns["lateral_dev_m"][row - first] * 1e3, abs=1e-4)
    # every station, every column: the sheet holds the computed values (empty = NaN)
    sheet = np.array([[np.nan if v is None else v for v in r]
                      for r in ws.iter_rows(min_row=first, values_only=True)], dtype=float)
    assert sheet.shape == (N, len(res.report.columns))
    for k, col in enumerate(res.report.columns):
        want = (g.chainage_m if col.key in ("chainage_m", "station_km") else g.columns[col.key])
        want = col.display(want)
        np.testing.assert_array_equal(np.isnan(sheet[:, k]), np.isnan(want), err_msg=col.key)
        np.testing.assert_allclose(sheet[:, k], want, rtol=0, atol=1e-9, err_msg=col.key)
    # conditional formatting on every limited column, over all stations
    # (the grey italics of the stations beyond the outermost fixes, ISNUMBER alone, are not limits)
    cf = {str(r.sqref): r.rules[0].formula[0] for r in ws.conditional_formatting if ",OR(" in r.rules[0].formula[0]}
    jg = heads.index("Gauge dev [mm] (nominal 1435)") + 1
    L = ws.cell(1, jg).column_letter
    assert cf[f"{L}{first}:{L}{last}"] == f"AND(ISNUMBER({L}{first}),OR({L}{first}<-1.0,{L}{first}>1.0))"
    assert len(cf) == len(res.report.tolerances.limits)
    # charts: scatter with lines, x = the chainage column, y = the right columns, all N rows
    from openpyxl.chart import ScatterChart

    charts = wb["Charts"]._charts
    assert [ch.title.tx.rich.p[0].r[0].t for ch in charts] == ["Deviation from design", "Gauge deviation",
                                                               "Cant", "Cant deviation", "Twist"]
    want = [["Lateral dev [mm] +right", "Vertical dev [mm] +up"], ["Gauge dev [mm] (nominal 1435)"],
            ["Cant [mm] +left high", "Design cant [mm] +left high"], ["Cant dev [mm] +left high"],
            ["Twist 3 m [mm] +left high", "Twist less design 3 m [mm] +left high"]]
    limited = {lim.column for lim in res.report.tolerances.limits}
    by_header = {c.header: c.key for c in res.report.columns}
    colours = []
    for ch, names in zip(charts, want):
        assert isinstance(ch, ScatterChart) and ch.scatterStyle == "line"
        assert ch.x_axis.delete is False and ch.y_axis.delete is False
        assert ch.x_axis.tickLblPos == "low"                 # km labels at the bottom of the plot
        assert ch.x_axis.numFmt.formatCode == '0"+"000' and ch.x_axis.scaling.max == pytest.approx(g.chainage_m[-1])
        # the data series, then one dashed red tolerance series per limited parameter
        n_tol = sum(by_header[nm] in limited for nm in names)
        assert len(ch.series) == len(names) + n_tol
        for ser, name in zip(ch.series, names):
            L = ws.cell(1, heads.index(name) + 1).column_letter
            assert ser.xVal.numRef.f == f"'Track'!$A${first}:$A${last}"
            assert ser.yVal.numRef.f == f"'Track'!${L}${first}:${L}${last}"
            assert ser.tx.strRef.f == f"'Track'!{L}{head}"
        colours.append([str(ser.graphicalProperties.line.solidFill.srgbClr) for ser in ch.series[:len(names)]])
        for ser in ch.series[len(names):]:
            assert ser.graphicalProperties.line.prstDash == "dash" and "ChartData" in ser.yVal.numRef.f
    assert all(len(set(c)) == len(c) for c in colours)       # distinct colours within a chart
    # the gauge chart's tolerance lines stand at -1 and +1 mm on the hidden sheet
    tol = charts[1].series[1]
    ref = tol.yVal.numRef.f.split("!")[1].replace("$", "")
    vals = [c.value for row in wb["ChartData"][ref] for c in row]
    assert [v for v in vals if v is not None] == [-1.0, -1.0, 1.0, 1.0]


def test_print_settings_and_header_block(exported):
    """Every sheet: A4 landscape, page numbers in the footer, the header block (rows 1-7 or the
    Summary's rows) with "not given" for what nobody gave; the Track sheet prints in column
    groups with chainage and station on every page."""
    from openpyxl import load_workbook

    from survey.workbook import HEADER_ROWS, TABLE_ROW

    base, res = exported
    wb = load_workbook(base / "survey.xlsx")
    for ws in wb.worksheets:
        if ws.title == "ChartData":
            continue
        assert ws.page_setup.orientation == "landscape" and int(ws.page_setup.paperSize) == 9, ws.title
        assert ws.oddFooter.center.text == "Page &P of &N", ws.title
        assert ws.oddHeader.center.text == ws.title
        assert "=1+1" in ws.oddHeader.left.text
    for title in ("Track print", "Defects", "Fixes"):
        assert wb[title].print_title_rows == f"$1:${TABLE_ROW}"
        assert wb[title].sheet_properties.pageSetUpPr.fitToPage and wb[title].page_setup.fitToWidth == 1
        lines = [wb[title].cell(r, 1).value for r in range(2, HEADER_ROWS + 1)]
        assert lines[0].startswith("Project: =1+1") and "Line: not given" in lines[0]
        assert "IMU: not given" in lines[2] and "Software: trolley-survey" in lines[3]
        assert all(len(x) < 190 for x in lines)          # fits the printed width at 8 pt
        assert lines[5].startswith("Tolerance set: built-in set hsr_ballastless_static")
        assert not any("/tmp" in x or "pytest" in x for x in lines)     # no path of this machine
    track = wb["Track"]
    head, _ = track_table(track)
    assert track.print_title_cols == "$A:$B" and track.print_title_rows == f"${head}:${head}"
    assert track.freeze_panes == f"C{head + 1}"                         # frozen below the column header
    assert [b.id for b in track.col_breaks.brk] == [11, 17, 27, 33]    # positions | deviations | gauge, cant | ...
    summary = {r[0].value: r[1].value for r in wb["Summary"].iter_rows(min_row=1, max_col=2)}
    assert summary["Line"] == "not given" and summary["Total station serial number"] == "not given"
    assert summary["Tolerance set"].startswith("hsr_ballastless_static")
    assert summary["Software"].startswith("trolley-survey ")
    # the Charts sheet: two charts per page, a manual break between pages, no chart across one
    from survey.workbook import CHART_ROWS, CHARTS_PER_PAGE

    charts = wb["Charts"]
    rows = [ch.anchor._from.row + 1 for ch in charts._charts]
    breaks = [b.id for b in charts.row_breaks.brk]
    assert breaks == [TABLE_ROW + k * CHARTS_PER_PAGE * CHART_ROWS - 1 for k in range(1, len(breaks) + 1)]
    for r in rows:
        page_end = min([b for b in breaks if b >= r], default=10 ** 6)
        assert r + CHART_ROWS - 1 <= page_end


def test_a_defect_is_as_long_as_the_track_its_stations_cover_and_no_longer_than_the_survey(exported):
    from trolley.tolerances import Defect

    rep = exported[1].report
    s = rep.geometry.chainage_m

    def length(a, b):
        return rep.defect_length_m(Defect("gauge_dev", "gauge_dev_m", a, b, 0.002, 0.001, 1))

    assert length(s[10], s[41]) == pytest.approx(32 * STEP)           # 32 stations, mid-track
    assert length(s[10], s[10]) == pytest.approx(STEP)
    assert length(s[-31], s[-1]) == pytest.approx(30.5 * STEP)        # to the survey's end
    assert length(s[0], s[-1]) == pytest.approx(s[-1] - s[0])          # the whole survey


def test_defects_summary_and_hostile_text(exported):
    from openpyxl import load_workbook

    base, res = exported
    rep = res.report
    params = {d.parameter for d in rep.defects}
    assert {"gauge_dev", "chord30_5_lat", "versine_h_dev"} <= params
    gdef = [d for d in rep.defects if d.parameter == "gauge_dev"]
    assert len(gdef) == 1 and gdef[0].peak == pytest.approx(0.0025, abs=1e-9)
    assert 420.0 <= gdef[0].start_chainage_m <= gdef[0].end_chainage_m <= 421.0
    wb = load_workbook(base / "survey.xlsx")
    from survey.workbook import TABLE_ROW

    dws = wb["Defects"]
    dh = [c.value for c in dws[TABLE_ROW]]
    assert dh[2:6] == ["From [m]", "To [m]", "From [km+m]", "To [km+m]"]
    assert dws.cell(TABLE_ROW + len(rep.defects) + 1, 1).value is None      # the list ends there
    for r, d in enumerate(rep.defects, start=TABLE_ROW + 1):
        assert (dws.cell(r, 4).value, dws.cell(r, 6).value) == (pytest.approx(d.end_chainage_m),) * 2
        assert dws.cell(r, 5).value == pytest.approx(d.start_chainage_m)
        assert dws.cell(r, 6).number_format == '0"+"000.000'
        assert dws.cell(r, 7).value == pytest.approx(d.end_chainage_m - d.start_chainage_m + STEP)
        # peak and limit with the digits the limit is checked on (mm: 4, mm/m: 5)
        assert dws.cell(r, 8).number_format == dws.cell(r, 9).number_format
        assert dws.cell(r, 8).number_format == {"mm": "0.0000", "mm/m": "0.00000"}[dws.cell(r, 10).value]
    summary = {r[0].value: r[1].value for r in wb["Summary"].iter_rows(min_row=1, max_col=2)}
    assert summary["Result"] == "FAIL" and summary["Defects"] == len(rep.defects)
    assert summary["Project"] == "=1+1" and wb["Summary"]["B3"].data_type == "s"
    fx = wb["Fixes"]
    r = TABLE_ROW + 2
    cell = fx[f"B{r}"]
    assert cell.value == HOSTILE and cell.data_type == "s" and cell.quotePrefix
    assert fx[f"B{r + 1}"].value == "-12" and fx[f"B{r + 1}"].data_type == "s"
    assert fx[f"B{r + 2}"].value == "CP\\x014"                   # control character escaped, no crash
    assert fx[f"J{r + 1}"].value == "no" and fx[f"K{r + 1}"].value == "@NIS 40.0 > 11.3" and fx[f"K{r + 1}"].quotePrefix


def test_csv_is_numeric_and_injection_safe(exported):
    base, res = exported
    with open(base / "track_table.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    head = rows[0]
    assert head[0] == "chainage_m" and "lateral_dev_mm" in head and "twist_mm" in head
    assert len(rows) == N + 1
    j = head.index("gauge_dev_mm")
    vals = np.array([float(r[j]) if r[j] else np.nan for r in rows[1:]])
    np.testing.assert_allclose(vals, res.report.geometry.columns["gauge_dev_m"] * 1e3, atol=1e-4)
    # no text cell that a spreadsheet would evaluate: every cell is a number or empty
    for r in rows[1:]:
        for v in r:
            if v:
                float(v)


def test_csv_text_is_prefixed():
    from survey.sheet_text import csv_safe_text

    assert csv_safe_text(HOSTILE) == "'" + HOSTILE
    assert csv_safe_text("\tx") == "'\tx" and csv_safe_text("CP3") == "CP3"
    assert csv_safe_text("a\x00b") == "a\\x00b"


def test_plots_written_with_km_axis(exported):
    base, res = exported
    names = {p.name for p in res.plots}
    assert {"deviations.png", "gauge.png", "cant.png", "twist.png"} <= names
    for p in res.plots:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000
    assert km_label(1234.5) == "1+234.5" and km_label(12.0) == "0+012.0" and km_label(-20.0) == "-0+020.0"


def test_without_design_fixes_or_summary(tmp_path):
    from openpyxl import load_workbook

    out = _write_outputs(tmp_path / "o", with_design=False, with_fixes=False, with_summary=False)
    res = export_outputs(out / "track.csv", tmp_path / "a.xlsx", None, None, tolerances="en13848_5_alert")
    wb = load_workbook(tmp_path / "a.xlsx")
    from survey.workbook import TABLE_ROW

    assert "not found" in wb["Fixes"][f"A{TABLE_ROW}"].value
    assert "no field record" in wb["Free stations"][f"A{TABLE_ROW}"].value
    head, heads = track_table(wb["Track"])
    j = heads.index("Design E [m]") + 1
    assert all(wb["Track"].cell(head + r, j).value is None for r in (1, 100, N))
    assert any("no design" in n for n in res.report.notes)


def test_cli_export_and_clear_errors(tmp_path):
    from typer.testing import CliRunner

    from survey.cli import app

    out = _write_outputs(tmp_path / "o", with_design=False)
    runner = CliRunner()
    r = runner.invoke(app, ["export", str(out), "--xlsx", str(tmp_path / "x.xlsx"), "--twist-base", "6.25",
                            "--tolerances", "en13848_5_alert", "--fail-on-defects"])
    doc = json.loads(r.stdout)
    assert doc["stations"] == N and doc["tolerances"] == "en13848_5_alert"
    assert r.exit_code == (0 if doc["passed"] else 1)
    bad = tmp_path / "bad.csv"
    bad.write_text("chainage_m,E_m,N_m,H_m,sigma_E_mm,sigma_N_mm,sigma_H_mm\n0,1,2,3,.1,.1,.1\n"
                   "0.625,1,2,inf,.1,.1,.1\n", encoding="utf-8")
    r = runner.invoke(app, ["export", str(bad), "--xlsx", str(tmp_path / "y.xlsx")])
    assert r.exit_code == 2 and "row 3, column H_m" in r.stderr
    assert not (tmp_path / "y.xlsx").exists()
    r = runner.invoke(app, ["export", str(out), "--tolerances", "nope", "--xlsx", str(tmp_path / "z.xlsx")])
    assert r.exit_code == 2 and "nope" in r.stderr and not (tmp_path / "z.xlsx").exists()


def _soffice_convert(src, outdir, target: str):
    """Convert ``src`` with LibreOffice headless into ``outdir`` (own profile: no clash with a desktop)."""
    outdir.mkdir(exist_ok=True)
    p = subprocess.run(["soffice", f"-env:UserInstallation=file://{outdir}/lo-profile", "--headless",
                        "--convert-to", target, "--outdir", str(outdir), str(src)],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr


needs_soffice = pytest.mark.skipif(shutil.which("soffice") is None, reason="LibreOffice (soffice) not installed")


@needs_soffice
def test_libreoffice_opens_workbook(exported, tmp_path):
    """LibreOffice computes and shows the sheets as we wrote them (CSV export of every sheet)."""
    base, res = exported
    opts = "csv:Text - txt - csv (StarCalc):44,34,UTF8,1,,0,false,true,false,false,false,-1"
    _soffice_convert(base / "survey.xlsx", tmp_path, opts)
    with open(tmp_path / "survey-Track.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    head = next(i for i, r in enumerate(rows) if r[0] == "Chainage [m]")
    assert len(rows) == head + 1 + N and rows[0][2].startswith("Track") and rows[1][2].startswith("Project: =1+1")
    g = res.report.geometry
    j = rows[head].index("Cant [mm] +left high")
    vals = np.array([float(r[j]) for r in rows[head + 1:]])
    np.testing.assert_allclose(vals, g.columns["cant_m"] * 1e3, atol=1e-4)
    with open(tmp_path / "survey-Fixes.csv", newline="", encoding="utf-8") as f:
        fixes = list(csv.reader(f))
    from survey.workbook import TABLE_ROW

    assert fixes[TABLE_ROW + 1][1] == HOSTILE                # stayed text: not evaluated to "y"
    assert fixes[TABLE_ROW + 2][1] == "-12" and fixes[TABLE_ROW + 3][1] == "CP\\x014"
    with open(tmp_path / "survey-Summary.csv", newline="", encoding="utf-8") as f:
        summ = {r[0]: r[1] for r in csv.reader(f) if len(r) > 1}
    assert summ["Project"] == "=1+1" and summ["Result"] == "FAIL"
    with open(tmp_path / "survey-Defects.csv", newline="", encoding="utf-8") as f:
        drows = list(csv.reader(f))
    d0 = res.report.defects[0]
    assert drows[TABLE_ROW - 1][4:6] == ["From [km+m]", "To [km+m]"]
    assert float(drows[TABLE_ROW][5]) == pytest.approx(d0.end_chainage_m)     # raw values (not "as shown")


@needs_soffice
def test_libreoffice_round_trip_keeps_values_formats_and_charts(exported, tmp_path):
    """Saved again as .xlsx by LibreOffice and re-read with openpyxl: every Track value, the
    text cells, the conditional-formatting ranges and the charts with their series survive."""
    from openpyxl import load_workbook

    base, res = exported
    _soffice_convert(base / "survey.xlsx", tmp_path, "xlsx:Calc MS Excel 2007 XML")
    ours = load_workbook(base / "survey.xlsx")
    lo = load_workbook(tmp_path / "survey.xlsx")
    assert lo.sheetnames == ours.sheetnames
    head, heads = track_table(ours["Track"])
    assert track_table(lo["Track"]) == (head, heads)
    assert [lo["Track"].cell(r, 3).value for r in range(1, head)] == [ours["Track"].cell(r, 3).value
                                                                       for r in range(1, head)]  # header block
    a = np.array([[np.nan if v is None else v for v in r]
                  for r in ours["Track"].iter_rows(min_row=head + 1, values_only=True)], dtype=float)
    b = np.array([[np.nan if v is None else v for v in r]
                  for r in lo["Track"].iter_rows(min_row=head + 1, values_only=True)], dtype=float)
    assert a.shape == (N, len(res.report.columns))
    np.testing.assert_array_equal(a, b)                   # bit-identical numbers, same empty cells
    from survey.workbook import TABLE_ROW

    for ref in (f"B{TABLE_ROW + k}" for k in (2, 3, 4)):
        assert lo["Fixes"][ref].value == ours["Fixes"][ref].value and lo["Fixes"][ref].data_type == "s"
    assert lo["Summary"]["B3"].value == "=1+1" and lo["Summary"]["B3"].data_type == "s"
    assert lo["Track"].cell(head + 1, 2).number_format.replace("\\", "").replace('"', "") == "0+000.000"

    def cf(ws):
        return {str(r.sqref): r.rules[0].formula[0].split(",OR(")[0] for r in ws.conditional_formatting
                if ",OR(" in r.rules[0].formula[0]}

    assert cf(lo["Track"]) == cf(ours["Track"]) and len(cf(ours["Track"])) == len(res.report.tolerances.limits)

    def series(ws):
        return [[(s.xVal.numRef.f.replace("'", ""), s.yVal.numRef.f.replace("'", "")) for s in ch.series]
                for ch in ws._charts]

    assert series(lo["Charts"]) == series(ours["Charts"]) and len(series(ours["Charts"])) == 5
    assert all(ch.scatterStyle == "line" for ch in lo["Charts"]._charts)


def test_design_from_session_landxml(exported):
    base, res = exported
    g = res.report.geometry
    assert res.report.design_file.name == "alignment.xml"
    # the synthetic cant is the design cant; the design E/N are the track minus the lateral offset
    assert np.nanmax(np.abs(g.columns["cant_dev_m"])) < 1e-6
    assert np.nanmax(g.columns["design_cant_m"]) == pytest.approx(1.5 * np.sin(0.08), rel=1e-6)
    off = np.hypot(g.columns["E_m"] - g.columns["design_E_m"], g.columns["N_m"] - g.columns["design_N_m"])
    np.testing.assert_allclose(off, np.abs(g.columns["lateral_dev_m"]), atol=2e-6)


def test_a_limit_in_mm_on_a_column_shown_in_metres_compares_metres(tmp_path, exported):
    # [limits.E] max_mm = 0.5 on the E column (shown in m): the red cells compare the metre cell
    # values with 0.0005, the Summary row shows the limits in the column's unit
    from openpyxl import load_workbook

    base, _ = exported
    tol = tmp_path / "tol.toml"
    tol.write_text('format = "trolley-tolerances/1"\nname = "e"\ntitle = "E"\ndescription = "d"\n'
                   '[limits.E]\nmin_mm = -0.5\nmax_mm = 0.5\nsource = "test"\n', encoding="utf-8")
    res = export_outputs(base / "out", tmp_path / "e.xlsx", None, None, tolerances=str(tol))
    wb = load_workbook(tmp_path / "e.xlsx")
    ws = wb["Track"]
    heads = [c.value for c in ws[TABLE_ROW]]
    L = ws.cell(TABLE_ROW, heads.index("E [m]") + 1).column_letter
    (formula,) = [r.rules[0].formula[0] for r in ws.conditional_formatting if ",OR(" in r.rules[0].formula[0]]
    first = TRACK_FIRST_ROW
    assert formula == f"AND(ISNUMBER({L}{first}),OR({L}{first}<-0.0005,{L}{first}>0.0005))"
    rows = {r[0].value: r for r in wb["Summary"].iter_rows(min_row=1, max_col=13) if r[0].value}
    e_row = rows["E [m]"]
    assert (e_row[8].value, e_row[9].value) == (-0.0005, 0.0005)
    assert all(d.column == "E_m" for d in res.report.defects) and res.report.defects


def test_section_quality_takes_twist_less_design(exported):
    # the track's cant is its design's (0 -> 120 mm ramps at 100-150 m and 350-400 m): the
    # designed twist of the ramps is no irregularity, the twist itself is not zero there
    from trolley.sectionquality import section_quality

    from survey.workbook import section_table

    rep = exported[1].report
    keys, quals = section_table(rep)
    labels = [lab for _, lab in keys]
    assert "twist less design" in labels and "twist" not in labels
    q = quals[labels.index("twist less design")]
    assert np.nanmax(q.std) < 1e-6
    g = rep.geometry
    raw = section_quality(g.chainage_m, g.columns["twist_m"], step_m=g.step_m)
    assert np.nanmax(raw.std) > 1e-3


def test_the_summary_says_whether_the_lateral_sigma_took_the_e_n_covariance(tmp_path):
    """The Summary's "σ lateral" row said "E-N covariance not available" on every sheet, also when
    track.csv had cov_EN_mm2 and the Track sheet's σ lateral took it (the demo's)."""
    import openpyxl
    import pandas as pd

    def summary_row(xlsx):
        ws = openpyxl.load_workbook(xlsx)["Summary"]
        return next(r[1] for r in ws.iter_rows(values_only=True) if r[0] == "σ lateral")

    out = _write_outputs(tmp_path / "out", with_fixes=False)
    export_outputs(out, tmp_path / "without.xlsx", None, None)
    assert "E-N covariance not available" in summary_row(tmp_path / "without.xlsx")
    track = pd.read_csv(out / "track.csv")
    track["cov_EN_mm2"] = 0.1                      # rho 0.5 with sigma_E 0.4, sigma_N 0.5
    track.to_csv(out / "track.csv", index=False, float_format="%.6f", na_rep="")
    export_outputs(out, tmp_path / "with.xlsx", tmp_path / "with.csv", None)
    text = summary_row(tmp_path / "with.xlsx")
    assert "not available" not in text and "E-N covariance (track.csv cov_EN_mm2)" in text
    # and the sheet's sigma is the one with the covariance (the claim is true)
    table = pd.read_csv(tmp_path / "with.csv")
    i = 50                                          # on the first straight: heading 0.3 rad
    psi = np.arctan2(np.diff(table["E_m"])[i], np.diff(table["N_m"])[i])
    c, s = np.cos(psi), np.sin(psi)
    with_cov = np.sqrt(c * c * 0.16 + s * s * 0.25 - 2 * s * c * 0.1)
    assert table["sigma_lateral_mm"][i] == pytest.approx(with_cov, abs=2e-3)
