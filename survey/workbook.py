"""The Excel survey sheet (openpyxl): Summary, Track, Defects, Fixes and Charts sheets.

The workbook is built with openpyxl (styles, frozen panes, autofilter, conditional formatting,
scatter charts, text cells). The bulk of the Track sheet (one row per station, ~45 numeric
columns) is the exception: openpyxl (without lxml) writes about 100 k cells/s, so 16 000 stations
would take ~7 s. openpyxl writes the header row and one template row carrying each column's
number-format style; the station rows are then generated as SpreadsheetML text with the same
style ids and spliced into ``<sheetData>`` of that sheet's part (and ``<dimension>`` fixed). The
result is an ordinary .xlsx that openpyxl, Excel and LibreOffice read (tests re-read it with
openpyxl and convert it with LibreOffice).

Text from users and files goes through :func:`survey.sheet_text.put_text` (never a formula).

References
----------
shared/research/protocols.md 6 (columns, formula injection); deps.md 5 (openpyxl traps: axes
``delete = False``, write speed).
"""
from __future__ import annotations

import math
import re
import time
import zipfile
from datetime import datetime, timezone
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from survey.atomicwrite import atomic_path
from survey.sheet_text import put_text
from survey.track_reader import EQUIPMENT
from survey.track_table import KM_FORMAT, SurveyReport, column_values, conventions, limit_in_display

_NS_MAIN = "http://schemas.openxmlformats.org/spreadsheetml/2006/main"
_NS_REL = "http://schemas.openxmlformats.org/officeDocument/2006/relationships"
_NS_PKG_REL = "http://schemas.openxmlformats.org/package/2006/relationships"

TRACK_SHEET = "Track"
#: freeze the header row and the chainage + station columns
TRACK_FREEZE = "C2"


def _col_letter(i: int) -> str:
    from openpyxl.utils import get_column_letter

    return get_column_letter(i)


def _num(ws, row: int, col: int, value, fmt: str | None = None):
    """A numeric cell (NaN / None -> empty)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ws.cell(row=row, column=col)
    c = ws.cell(row=row, column=col, value=float(value) if not isinstance(value, (int, np.integer)) else int(value))
    if fmt:
        c.number_format = fmt
    return c


def _header(ws, row: int, names: list[str]) -> None:
    from openpyxl.styles import Alignment, Font, PatternFill

    bold, fill = Font(bold=True), PatternFill("solid", fgColor="DDEBF7")
    for j, name in enumerate(names, start=1):
        c = put_text(ws, row, j, name)
        c.font, c.fill = bold, fill
        c.alignment = Alignment(wrap_text=True, vertical="top")


def _summary_sheet(ws, rep: SurveyReport) -> None:
    from openpyxl.styles import Font, PatternFill

    info, g, cfg = rep.info, rep.geometry, rep.geometry.config
    bold = Font(bold=True)
    ws.column_dimensions["A"].width = 34
    ws.column_dimensions["B"].width = 52
    r = 1
    c = put_text(ws, r, 1, "Track survey sheet")
    c.font = Font(bold=True, size=14)
    r += 2

    def kv(key, value, fmt=None):
        nonlocal r
        put_text(ws, r, 1, key).font = bold
        if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
            _num(ws, r, 2, float(value) if isinstance(value, (float, np.floating)) else int(value), fmt)
        else:
            put_text(ws, r, 2, "" if value is None else value)
        r += 1

    kv("Project", info.project or "(not given)")
    kv("Session", info.session or "(not given)")
    kv("Session folder", info.session_dir or "(not given)")
    kv("Track file", str(rep.track_csv))
    kv("Written (UTC)", datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S"))
    kv("Stations", int(g.chainage_m.size))
    kv("Chainage from [m]", float(g.chainage_m[0]), KM_FORMAT)
    kv("Chainage to [m]", float(g.chainage_m[-1]), KM_FORMAT)
    kv("Station step [m]", float(g.step_m), "0.000")
    if g.resampled:
        kv("Note", "input chainage not uniform: values interpolated linearly onto the grid")
    r += 1
    put_text(ws, r, 1, "Equipment").font = Font(bold=True, size=12)
    r += 1
    eq = info.equipment
    kv("IMU", eq.get("imu_name") or info.imu_name or "(not given)")
    legacy = {"gyro_bias_instability_deg_h": info.gyro_bias_instability_deg_h,
              "gyro_arw_deg_sqrt_h": info.gyro_arw_deg_sqrt_h}
    for key, (label, fmt) in EQUIPMENT.items():
        if key == "rail_spacing_m":
            kv(label, cfg.rail_spacing_m, fmt)          # the values the geometry used
        elif key == "nominal_gauge_mm":
            kv(label, cfg.nominal_gauge_m * 1e3, fmt)
        elif key == "prism_lever_arm_m":
            v = eq.get(key)
            kv(label, ", ".join(f"{x:.3f}" for x in v) if v else "(not given)")
        else:
            v = eq.get(key, legacy.get(key, math.nan))
            kv(label, v if math.isfinite(v) else "(not given)", fmt)
    kv("Equipment figures from", info.equipment_source or "(not given: summary.json and session.toml lack them)")
    kv("Smoother", info.smoother or "(not given)")
    r += 1
    put_text(ws, r, 1, "Control-point fixes").font = Font(bold=True, size=12)
    r += 1
    kv("Fixes used", info.fixes_used if info.fixes_used is not None else "(not given)")
    kv("Fixes rejected", info.fixes_rejected if info.fixes_rejected is not None else "(not given)")
    kv("RMS innovation [mm]", info.rms_innovation_mm, "0.00")
    kv("Max position sigma [mm]", info.max_sigma_mm, "0.00")
    if not info.present:
        kv("Note", "summary.json not found next to track.csv: equipment and fix figures unknown")
    r += 1
    put_text(ws, r, 1, "Design and conventions").font = Font(bold=True, size=12)
    r += 1
    kv("Design alignment", str(rep.design_file) if rep.design_file else "none: design columns empty")
    for name, text in conventions(cfg):
        kv(name, text)
    kv("Twist", f"cant(s) - cant(s - {cfg.twist_base_m:g} m)")
    kv("Gauge change rate", f"(gauge(s) - gauge(s - {cfg.gauge_rate_base_m:g} m)) / {cfg.gauge_rate_base_m:g} m")
    kv("Long chords", ", ".join(f"{a:g} m / {b:g} m" for a, b in cfg.long_chords_m))
    kv("Bands", "zero-phase Butterworth band-pass of the deviations, -3 dB at the band edges")
    kv("σ lateral", "from σE, σN projected on the track normal (E-N covariance not available)")
    for note in rep.notes:
        kv("Note", note)
    r += 1
    put_text(ws, r, 1, "Tolerances").font = Font(bold=True, size=12)
    r += 1
    kv("Tolerance set", f"{rep.tolerances.name}: {rep.tolerances.title}")
    kv("Tolerance file", rep.tolerances.origin)
    kv("Defects", len(rep.defects))
    res = put_text(ws, r, 1, "Result")
    res.font = bold
    passed = rep.passed
    c = put_text(ws, r, 2, "PASS" if passed else "FAIL")
    c.font = Font(bold=True, color="006100" if passed else "9C0006")
    c.fill = PatternFill("solid", fgColor="C6EFCE" if passed else "FFC7CE")
    r += 1
    unchecked = [lim.parameter for lim in rep.tolerances.limits if rep.stats[lim.column].count == 0]
    if unchecked:
        kv("Not checked (no values)", ", ".join(unchecked))
    r += 1

    put_text(ws, r, 1, "Statistics per parameter").font = Font(bold=True, size=12)
    r += 1
    heads = ["Parameter", "Unit", "Count", "Mean", "Std", "Min", "Max", "RMS", "Lower limit",
             "Upper limit", "Stations beyond", "Defects", "Limit source"]
    _header(ws, r, heads)
    r += 1
    limits = {lim.column: lim for lim in rep.tolerances.limits}
    n_def: dict[str, int] = {}
    n_st: dict[str, int] = {}
    for d in rep.defects:
        n_def[d.column] = n_def.get(d.column, 0) + 1
        n_st[d.column] = n_st.get(d.column, 0) + d.stations
    for col in rep.columns:
        if col.key in ("chainage_m", "station_km") or col.unit == "m":
            continue
        st = rep.stats[col.key]
        put_text(ws, r, 1, col.header)
        put_text(ws, r, 2, col.unit)
        _num(ws, r, 3, st.count)
        for j, v in enumerate((st.mean, st.std, st.minimum, st.maximum, st.rms), start=4):
            _num(ws, r, j, float(col.display(np.array([v]))[0]), col.number_format)
        lim = limits.get(col.key)
        if lim is not None:
            lo, hi, _ = limit_in_display(lim)
            _num(ws, r, 9, lo, col.number_format)
            _num(ws, r, 10, hi, col.number_format)
            _num(ws, r, 11, n_st.get(col.key, 0))
            _num(ws, r, 12, n_def.get(col.key, 0))
            put_text(ws, r, 13, "example value" + (f" ({lim.note})" if lim.note else "") if lim.example
                     else lim.source)
        r += 1
    for j, w in enumerate((34, 8, 8, 10, 10, 10, 10, 10, 11, 11, 9, 8, 60), start=1):
        if j > 2:
            ws.column_dimensions[_col_letter(j)].width = w


def _defects_sheet(ws, rep: SurveyReport) -> None:
    heads = ["#", "Parameter", "From [m]", "To [m]", "From [km+m]", "To [km+m]", "Length [m]", "Peak",
             "Limit", "Unit", "Stations", "Limit source"]
    _header(ws, 1, heads)
    ws.freeze_panes = "A2"
    limits = {lim.column: lim for lim in rep.tolerances.limits}
    by_key = {c.key: c for c in rep.columns}
    for i, d in enumerate(rep.defects, start=1):
        r = i + 1
        lim = limits[d.column]
        col = by_key.get(d.column)
        fmt = col.number_format if col else "0.000"
        _num(ws, r, 1, i)
        put_text(ws, r, 2, col.header if col else d.parameter)
        _num(ws, r, 3, d.start_chainage_m, "0.000")
        _num(ws, r, 4, d.end_chainage_m, "0.000")
        _num(ws, r, 5, d.start_chainage_m, KM_FORMAT)
        _num(ws, r, 6, d.end_chainage_m, KM_FORMAT)
        _num(ws, r, 7, d.end_chainage_m - d.start_chainage_m + rep.geometry.step_m, "0.000")
        conv = col.display if col else (lambda x: x)
        _num(ws, r, 8, float(conv(np.array([d.peak]))[0]), fmt)
        _num(ws, r, 9, float(conv(np.array([d.limit]))[0]), fmt)
        put_text(ws, r, 10, col.unit if col else "")
        _num(ws, r, 11, d.stations)
        put_text(ws, r, 12, "example value" if lim.example else lim.source)
    if not rep.defects:
        put_text(ws, 2, 2, "no value beyond tolerance")
    else:
        ws.auto_filter.ref = f"A1:L{len(rep.defects) + 1}"
    for j, w in enumerate((6, 34, 11, 11, 12, 12, 10, 10, 10, 7, 9, 60), start=1):
        ws.column_dimensions[_col_letter(j)].width = w


def _fixes_sheet(ws, rep: SurveyReport) -> None:
    if rep.fixes is None:
        put_text(ws, 1, 1, "fixes.csv not found next to track.csv: no per-stop fix information")
        ws.column_dimensions["A"].width = 70
        return
    heads = ["t [s]", "Point", "E [m]", "N [m]", "H [m]", "Innovation E [mm]", "Innovation N [mm]",
             "Innovation H [mm]", "NIS", "Accepted", "Reason"]
    _header(ws, 1, heads)
    ws.freeze_panes = "C2"
    for i, f in enumerate(rep.fixes, start=2):
        _num(ws, i, 1, f.t_s, "0.000")
        put_text(ws, i, 2, f.point)
        for j, v in enumerate((f.E_m, f.N_m, f.H_m), start=3):
            _num(ws, i, j, v, "0.0000")
        for j, v in enumerate((f.innov_E_m, f.innov_N_m, f.innov_H_m), start=6):
            _num(ws, i, j, v * 1e3 if math.isfinite(v) else v, "0.00")
        _num(ws, i, 9, f.nis, "0.00")
        put_text(ws, i, 10, "yes" if f.accepted else "no")
        put_text(ws, i, 11, f.reason)
    ws.auto_filter.ref = f"A1:K{len(rep.fixes) + 1}"
    for j, w in enumerate((10, 16, 14, 14, 10, 11, 11, 11, 8, 9, 40), start=1):
        ws.column_dimensions[_col_letter(j)].width = w


#: charts on the Charts sheet: title, y-axis title, geometry columns
CHARTS = [
    ("Deviation from design", "deviation [mm]", ["lateral_dev_m", "vertical_dev_m"]),
    ("Gauge deviation", "gauge - nominal [mm]", ["gauge_dev_m"]),
    ("Cant", "cant [mm]", ["cant_m", "design_cant_m", "cant_dev_m"]),
    ("Twist", "twist [mm]", ["twist_m", "twist_dev_m"]),
]


#: x-axis tick labels of the charts: km+m without decimals (1+234)
CHART_KM_FORMAT = '0"+"000'


def _charts_sheet(ws, track_ws_title: str, rep: SurveyReport, n: int) -> None:
    """Scatter charts with straight lines (``scatterStyle`` "line", which Excel and LibreOffice
    draw as line charts): x = the Track sheet's chainage column (numeric, so the axis is scaled
    in metres, unlike a LineChart's category axis), labelled km+m; y = one column per series."""
    from openpyxl.chart import Reference, ScatterChart, Series

    index = {c.key: j for j, c in enumerate(rep.columns, start=1)}
    track = ws.parent[track_ws_title]
    xref = Reference(track, min_col=index["chainage_m"], min_row=2, max_row=n + 1)
    s0, s1 = float(rep.geometry.chainage_m[0]), float(rep.geometry.chainage_m[-1])
    put_text(ws, 1, 1, "Charts of the Track sheet against chainage [km+m]")
    row = 3
    for title, ytitle, keys in CHARTS:
        keys = [k for k in keys if rep.stats[k].count > 0]
        if not keys:
            continue
        ch = ScatterChart(scatterStyle="line")
        ch.title = title
        ch.style = 13
        ch.x_axis.title = "chainage [km+m]"
        ch.y_axis.title = ytitle
        ch.x_axis.number_format = CHART_KM_FORMAT
        ch.x_axis.scaling.min, ch.x_axis.scaling.max = s0, s1
        ch.x_axis.delete = False      # openpyxl 3.1 omits <delete val=0>: Excel would hide the axes
        ch.y_axis.delete = False
        ch.height, ch.width = 8.5, 26.0
        for k in keys:
            yref = Reference(track, min_col=index[k], min_row=1, max_row=n + 1)
            s = Series(yref, xref, title_from_data=True)
            s.marker.symbol = "none"
            s.smooth = False
            ch.series.append(s)
        ws.add_chart(ch, f"A{row}")
        row += 18


def _track_sheet_head(ws, rep: SurveyReport, n: int) -> None:
    """Header, template row 2 (styles), widths, freeze, autofilter, conditional formats."""
    from openpyxl.formatting.rule import FormulaRule
    from openpyxl.styles import Font, PatternFill

    _header(ws, 1, [c.header for c in rep.columns])
    ws.row_dimensions[1].height = 45
    for j, col in enumerate(rep.columns, start=1):
        c = ws.cell(row=2, column=j, value=0.0)
        c.number_format = col.number_format
        ws.column_dimensions[_col_letter(j)].width = 11 if col.unit != "m" else 13
    ws.freeze_panes = TRACK_FREEZE
    last = _col_letter(len(rep.columns))
    ws.auto_filter.ref = f"A1:{last}{n + 1}"
    red = PatternFill("solid", fgColor="FFC7CE", bgColor="FFC7CE")
    font = Font(color="9C0006")
    index = {c.key: j for j, c in enumerate(rep.columns, start=1)}
    for lim in rep.tolerances.limits:
        j = index.get(lim.column)
        if j is None:
            continue
        lo, hi, _ = limit_in_display(lim)
        L = _col_letter(j)
        conds = []
        if math.isfinite(lo):
            conds.append(f"{L}2<{lo!r}")
        if math.isfinite(hi):
            conds.append(f"{L}2>{hi!r}")
        # ISNUMBER: empty cells (no value) are not exceedances
        formula = f"AND(ISNUMBER({L}2),OR({','.join(conds)}))"
        ws.conditional_formatting.add(f"{L}2:{L}{n + 1}", FormulaRule(formula=[formula], fill=red, font=font))


def _sheet_part(z: zipfile.ZipFile, title: str) -> str:
    """Zip member name of the worksheet called ``title``."""
    wb = ET.fromstring(z.read("xl/workbook.xml"))
    rid = None
    for sh in wb.iter(f"{{{_NS_MAIN}}}sheet"):
        if sh.get("name") == title:
            rid = sh.get(f"{{{_NS_REL}}}id")
    rels = ET.fromstring(z.read("xl/_rels/workbook.xml.rels"))
    for rel in rels.iter(f"{{{_NS_PKG_REL}}}Relationship"):
        if rel.get("Id") == rid:
            target = rel.get("Target")
            return target.lstrip("/") if target.startswith("/") else "xl/" + target
    raise RuntimeError(f"worksheet {title!r} not found in the workbook package")


def _station_rows_xml(rep: SurveyReport, styles: dict[str, str]) -> str:
    """SpreadsheetML ``<row>`` elements 2..n+1 of the Track sheet.

    The values come per column as numpy arrays; the text is built by one comprehension per
    column (repr: the shortest text that reads back to the same float). Measured on 16 000 x 45
    values, this (0.22-0.29 s) beats every vectorised alternative tried with identical output:
    numpy StringDType concatenation (np.strings.add, 0.68 s; its float-to-text is slower than
    repr) and one %-template per run of rows with the same empty cells (0.28-0.43 s).
    """
    n = rep.geometry.chainage_m.size
    rows_num = [str(i) for i in range(2, n + 2)]
    per_col = []
    for j, col in enumerate(rep.columns, start=1):
        L = _col_letter(j)
        s = styles.get(L, "0")
        vals = column_values(col, rep.geometry).tolist()
        pre = f'<c r="{L}'
        mid = f'" s="{s}"><v>'
        per_col.append([f"{pre}{r}{mid}{v!r}</v></c>" if v == v else ""   # v != v: NaN -> no cell
                        for r, v in zip(rows_num, vals)])
    return "".join(f'<row r="{r}">' + "".join(cells) + "</row>" for r, cells in zip(rows_num, zip(*per_col)))


def _splice_track_rows(path: Path, rep: SurveyReport, timings: dict[str, float]) -> None:
    """Replace the template row 2 of the Track sheet by all station rows (in place)."""
    t0 = time.perf_counter()
    n = rep.geometry.chainage_m.size
    with zipfile.ZipFile(path) as z:
        part = _sheet_part(z, TRACK_SHEET)
        members = [(i, z.read(i.filename)) for i in z.infolist()]
    xml = dict((i.filename, data) for i, data in members)[part].decode("utf-8")
    m = re.search(r'<row r="2"[^>]*>.*?</row>', xml, flags=re.S)
    if m is None:
        raise RuntimeError("template row 2 missing from the Track sheet")
    styles = dict(re.findall(r'<c r="([A-Z]+)2"[^>]*?\ss="(\d+)"', m.group(0)))
    rows = _station_rows_xml(rep, styles)
    xml = xml[:m.start()] + rows + xml[m.end():]
    t1 = time.perf_counter()
    timings["rows_xml"] = t1 - t0
    last = _col_letter(len(rep.columns))
    xml = re.sub(r'<dimension ref="[^"]*"\s*/>', f'<dimension ref="A1:{last}{n + 1}"/>', xml, count=1)
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as out:
            for info, data in members:
                payload = xml.encode("utf-8") if info.filename == part else data
                zi = zipfile.ZipInfo(info.filename, date_time=info.date_time)
                zi.compress_type = zipfile.ZIP_DEFLATED
                out.writestr(zi, payload, compresslevel=1)
    timings["zip"] = time.perf_counter() - t1


def _print_setup(ws, landscape: bool) -> None:
    """Print every sheet one page wide (the client prints the sheet), header row repeated."""
    ws.page_setup.orientation = "landscape" if landscape else "portrait"
    ws.page_setup.paperSize = ws.PAPERSIZE_A4
    ws.page_setup.fitToWidth = 1
    ws.page_setup.fitToHeight = 0  # as many pages down as needed
    ws.sheet_properties.pageSetUpPr.fitToPage = True
    if ws.title != "Summary" and ws.title != "Charts":
        ws.print_title_rows = "1:1"


def write_workbook(path: Path, rep: SurveyReport, timings: dict[str, float] | None = None) -> Path:
    """Write the survey workbook to ``path`` atomically (temp file + rename).

    Parameters
    ----------
    path : .xlsx file to write.
    rep : the survey report.
    timings : if given, filled with seconds per stage: "openpyxl_build", "openpyxl_save"
        (openpyxl's share), "rows_xml" (station rows as XML), "zip" (re-packing).

    Returns
    -------
    path
    """
    from openpyxl import Workbook

    path = Path(path)
    if rep.geometry.chainage_m.size + 1 > 1_048_576:
        raise ValueError(f"{path}: {rep.geometry.chainage_m.size} stations exceed the 1 048 575 data rows "
                         "of an Excel sheet; export a shorter stretch or use --csv")
    timings = {} if timings is None else timings
    t0 = time.perf_counter()
    n = rep.geometry.chainage_m.size
    wb = Workbook()
    summary = wb.active
    summary.title = "Summary"
    track = wb.create_sheet(TRACK_SHEET)
    defects = wb.create_sheet("Defects")
    fixes = wb.create_sheet("Fixes")
    charts = wb.create_sheet("Charts")
    _summary_sheet(summary, rep)
    _track_sheet_head(track, rep, n)
    _defects_sheet(defects, rep)
    _fixes_sheet(fixes, rep)
    _charts_sheet(charts, TRACK_SHEET, rep, n)
    for ws, landscape in ((summary, True), (track, True), (defects, True), (fixes, True), (charts, True)):
        _print_setup(ws, landscape)
    with atomic_path(path) as tmp:
        t1 = time.perf_counter()
        timings["openpyxl_build"] = t1 - t0
        wb.save(tmp)
        timings["openpyxl_save"] = time.perf_counter() - t1
        _splice_track_rows(tmp, rep, timings)
    return path
