"""The PDF survey report (matplotlib's PDF backend, ``PdfPages``): what a client signs.

Pages, A4 landscape, each with the project, line, track and chainage at the top and the
software, "page i of N" and the tolerance set at the bottom:

1. cover: the header block (survey/surveyheader.py) and the verdict;
2. summary: fixes, overlap checks, what was not checked (``survey.export.unchecked_notes``), and
   the statistics of every parameter against its limit;
3. strip charts, one page per kilometre of chainage (the panels of survey/plots.py: deviations
   with their 1-sigma band, gauge, cant deviation, twist, with fixes, stops and tolerances);
4. the single defects (:data:`DEFECT_ROWS` a page) and the track quality per 200 m section;
5. free-station QA: every station setup with its residuals, the overlap checks with their
   verdict, and the fixes rejected or undone.

The file is made in memory and written in one step (temporary file + rename), so a failure
leaves no partial report.
"""
from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from survey.atomicwrite import write_bytes_atomic
from survey.plots import draw_panel, km_axis, km_label, panel_marks
from survey.surveyheader import header_rows
from survey.track_table import SurveyReport, limit_in_column, limit_text

#: A4 landscape, inches
PAGE_SIZE_IN = (11.69, 8.27)
#: strip-chart panels of each kilometre page (those with values are drawn)
STRIP_PANELS = [["lateral_dev_m"], ["vertical_dev_m"], ["gauge_dev_m"], ["cant_dev_m"], ["twist_m"]]
#: strip length of one page, m
STRIP_M = 1000.0
#: line spacing of the tables (multiples of the font's line height)
LINESPACING = 1.3
#: table rows per page
DEFECT_ROWS = 50
QA_ROWS = 56


@dataclass(frozen=True)
class PdfReport:
    """A written report: its path and the titles of its pages, in order."""

    path: Path
    pages: tuple[str, ...]


def _frame(fig, rep: SurveyReport, title: str, page: int, total: int) -> None:
    """Page header and footer."""
    h = dict(header_rows(rep))
    fig.text(0.03, 0.975, f"{h['Project']}  |  line {h['Line']}  |  track {h['Track']}", fontsize=7, va="top")
    fig.text(0.5, 0.975, title, fontsize=9, va="top", ha="center", weight="bold")
    fig.text(0.97, 0.975, h["Chainage"].split(" (")[0], fontsize=7, va="top", ha="right")
    fig.text(0.03, 0.015, h["Software"], fontsize=7)
    fig.text(0.5, 0.015, f"page {page} of {total}", fontsize=7, ha="center")
    fig.text(0.97, 0.015, f"tolerances {rep.tolerances.name}", fontsize=7, ha="right")


#: the table font: monospaced, so the columns of a row line up as text (DejaVu Sans Mono's advance)
TABLE_FONT = "DejaVu Sans Mono"
_MONO_ADVANCE_EM = 0.602


def _row_pitch(fig, fontsize: float) -> float:
    """Distance between table rows as a figure fraction: :data:`LINESPACING` times the font size."""
    return fontsize * LINESPACING / 72.0 / fig.get_figheight()


def _row_text(cells: list[str], chars: list[int]) -> str:
    """One table row as monospaced text: each cell padded (or cut, ending in an ellipsis) to its
    column's width in characters."""
    out = []
    for text, n in zip(cells, chars):
        text = str(text)
        out.append(text.ljust(n) if len(text) < n else text[:max(n - 2, 0)] + "… ")
    return "".join(out).rstrip()


def _table(ax, rows: list[list[str]], heads: list[str] | None, widths: list[float] | None = None,
           red: set[int] = frozenset(), fontsize: float = 7.0, bold: set[int] = frozenset(),
           subheads: set[int] = frozenset()) -> None:
    """A table at the top of ``ax``: one monospaced text per row, each at its own computed height
    (row ``i``'s centre at ``top - (i + 1.5) * pitch``), so rows stay on their rules and shading
    down the page (matplotlib's Table draws every cell as its own text and took 15 s for 1100
    cells; one multi-line text per column drifted from the shading by about a line near the
    foot of a page). ``heads`` (if given) is a blue header row; rows in ``subheads`` are header
    rows of a section (blue, bold), in ``bold`` titles spanning the row, in ``red`` shaded red."""
    from matplotlib.patches import Rectangle

    ax.axis("off")
    fig = ax.figure
    box = ax.get_position()
    ncol = len(heads) if heads else max(len(r) for r in rows)
    widths = widths or [1.0 / ncol] * ncol
    char_w = _MONO_ADVANCE_EM * fontsize / 72.0 / fig.get_figwidth()        # figure fraction per character
    total = int((box.width - 0.006) / char_w)
    chars = [int(w / sum(widths) * total) for w in widths]
    chars[-1] = total - sum(chars[:-1])
    pitch = _row_pitch(fig, fontsize)
    top = box.y1
    lines = ([(heads, "head")] if heads else []) + [
        (r, "sub" if i in subheads else "title" if i in bold else "row") for i, r in enumerate(rows)]
    first = 1 if heads else 0
    for k, (cells, kind) in enumerate(lines):
        y = top - (k + 1) * pitch
        fill = ("#DDEBF7" if kind in ("head", "sub") else
                "#FFC7CE" if kind == "row" and (k - first) in red else None)
        if fill:
            fig.patches.append(Rectangle((box.x0, y), box.width, pitch, transform=fig.transFigure,
                                         facecolor=fill, edgecolor="none", zorder=0))
        text = _row_text(cells[:1], [total]) if kind == "title" else _row_text(cells, chars)
        fig.text(box.x0 + 0.003, y + 0.5 * pitch, text, fontsize=fontsize, va="center", family=TABLE_FONT,
                 weight="normal" if kind == "row" else "bold")


def _fmt(x: float, digits: int = 2) -> str:
    return "" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _cover(fig, rep: SurveyReport) -> None:
    fig.text(0.05, 0.92, "Track survey report", fontsize=20, weight="bold")
    passed = rep.passed
    fig.text(0.05, 0.875, (f"PASS: {rep.no_defects_text}" if passed else
                           f"FAIL: {len(rep.defects)} defect(s) beyond tolerance"),
             fontsize=13, weight="bold", color="#006100" if passed else "#9C0006")
    ax = fig.add_axes([0.05, 0.06, 0.9, 0.78])
    rows = [[label, text] for label, text in header_rows(rep)]
    _table(ax, rows, ["Field", "Value"], [0.25, 0.75], fontsize=8)


#: the most lines one note takes on the summary page (the page holds the statistics table too)
NOTE_LINES = 4


def _summary(fig, rep: SurveyReport) -> None:
    from survey.workbook import _field_only_rejections

    info, rec = rep.info, rep.record
    field_rej = len(_field_only_rejections(rep))
    lines = [
        f"Stations: {rep.geometry.chainage_m.size}, step {rep.geometry.step_m:g} m",
        f"Fixes used: {info.fixes_used if info.fixes_used is not None else 'not given'}; rejected by the filter: "
        f"{info.fixes_rejected if info.fixes_rejected is not None else 'not given'}; rejected or undone in the field: "
        + (str(field_rej) if rec is not None else "not known (no field record)"),
        f"RMS innovation {_fmt(info.rms_innovation_mm)} mm, max position sigma {_fmt(info.max_sigma_mm)} mm",
    ]
    if rec is not None:
        bad = [o.new_point for o in rec.overlaps if not o.within]
        held = [o for o in rec.overlaps if not o.within and o.consistent]
        lines.append(f"Station setups: {len(rec.setups)}; overlap checks: {len(rec.overlaps)}, "
                     f"{len(bad)} outside the tolerance" + (f" ({', '.join(bad)})" if bad else "")
                     + (f", of them within {held[0].limit_text} of the setups' own uncertainty: "
                        f"{', '.join(o.new_point for o in held)}" if held else ""))
    lines.append(f"Defects: {len(rep.defects)} against {rep.tolerances.name}")
    import textwrap

    from survey.export import unchecked_notes

    for note in unchecked_notes(rep):   # what was not checked: a PASS must not hide it
        # at most NOTE_LINES lines each: a note listing 130 gaps took the page, and the statistics
        # table below got a negative height (ValueError, no PDF)
        lines += textwrap.wrap(f"Note: {note}", 150, subsequent_indent="    ", max_lines=NOTE_LINES,
                               placeholder=" ... (in full: the workbook's Summary, export --json's notes)")
    for i, t in enumerate(lines):
        fig.text(0.05, 0.92 - 0.03 * i, t, fontsize=9)
    limits = {lim.column: lim for lim in rep.tolerances.limits}
    n_def: dict[str, int] = {}
    for d in rep.defects:
        n_def[d.column] = n_def.get(d.column, 0) + 1
    rows, red = [], set()
    for col in rep.columns:
        if col.unit == "m" or col.key not in rep.stats or rep.stats[col.key].count == 0:
            continue
        st = rep.stats[col.key]
        conv = lambda v: float(col.display(np.array([v]))[0])  # noqa: E731
        lim = limits.get(col.key)
        lo, hi = limit_in_column(lim, col) if lim is not None else (-math.inf, math.inf)
        if n_def.get(col.key):
            red.add(len(rows))
        # the sheet's digits; a min or max just beyond its limit and the limits with the digits
        # they are checked on (a red row must not read "max 1.00, limit 1.00")
        rows.append([col.header, col.unit, str(st.count), col.text(conv(st.mean)), col.text(conv(st.std)),
                     col.text(conv(st.minimum), lo, hi), col.text(conv(st.maximum), lo, hi),
                     limit_text(lo, col.shown_digits, col.kept_digits),
                     limit_text(hi, col.shown_digits, col.kept_digits),
                     str(n_def.get(col.key, 0)) if lim is not None else ""])
        if len(rows) >= 40:
            break
    ax = fig.add_axes([0.05, 0.06, 0.9, 0.92 - 0.03 * len(lines) - 0.08])
    _table(ax, rows, ["Parameter", "Unit", "Count", "Mean", "Std", "Min", "Max", "Lower limit", "Upper limit",
                      "Defects"], [0.34, 0.06, 0.06, 0.07, 0.07, 0.07, 0.07, 0.09, 0.09, 0.06], red, fontsize=6.0)


def _strip(fig, rep: SurveyReport, a: float, b: float, marks) -> None:
    panels = [p for p in STRIP_PANELS if all(k in rep.stats and rep.stats[k].count > 0 for k in p)]
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False,
                        gridspec_kw={"left": 0.08, "right": 0.98, "top": 0.93, "bottom": 0.08, "hspace": 0.12})
    for ax, keys in zip(axes[:, 0], panels):
        if not draw_panel(ax, rep, keys, marks, xlim=(a, b)):
            ax.text(0.5, 0.5, "no values in this kilometre", transform=ax.transAxes, ha="center", fontsize=8)
            ax.set_ylabel(keys[0], fontsize=8)
        ax.tick_params(labelsize=7)
        leg = ax.get_legend()
        if leg is not None:
            leg.set_visible(ax is axes[0, 0])
    km_axis(axes[-1, 0], rep)


def _defects(fig, rep: SurveyReport, chunk) -> None:
    by_key = {c.key: c for c in rep.columns}
    rows = []
    for i, d in chunk:
        col = by_key.get(d.column)
        conv = (lambda v: float(col.display(np.array([v]))[0])) if col else (lambda v: v)
        digits = col.kept_digits if col else 3          # the digits the limits are checked on
        rows.append([str(i), col.header if col else d.parameter, km_label(rep.station(d.start_chainage_m), 3),
                     km_label(rep.station(d.end_chainage_m), 3), _fmt(rep.defect_length_m(d), 3),
                     _fmt(conv(d.peak), digits), _fmt(conv(d.limit), digits), col.unit if col else "", str(d.stations)])
    if not rows:
        fig.text(0.05, 0.9, "No value beyond tolerance.", fontsize=11)
        return
    ax = fig.add_axes([0.05, 0.06, 0.9, 0.86])
    _table(ax, rows, ["#", "Parameter", "From [km+m]", "To [km+m]", "Length [m]", "Peak", "Limit", "Unit",
                      "Stations"], [0.04, 0.38, 0.1, 0.1, 0.08, 0.08, 0.08, 0.06, 0.07])


def _quality(fig, rep: SurveyReport) -> None:
    from survey.workbook import section_table

    keys, quals = section_table(rep)
    fig.text(0.05, 0.92, "Track quality per 200 m section: standard deviation (EN 13848-6 style, 1/n) [mm]; "
                         "empty where fewer than half the stations have a value", fontsize=9)
    if not keys:
        fig.text(0.05, 0.88, "no parameter has values", fontsize=9)
        return
    q0 = quals[0]
    s = rep.geometry.chainage_m
    rows = [[str(i + 1), km_label(rep.station(max(q0.start_m[i], s[0])), 1),
             km_label(rep.station(min(q0.end_m[i], s[-1])), 1)]
            + [_fmt(q.std[i] * 1e3) for q in quals] for i in range(min(q0.start_m.size, 40))]
    ax = fig.add_axes([0.05, 0.06, 0.9, 0.84])
    _table(ax, rows, ["#", "From", "To"] + [f"SD {lab}" for _, lab in keys])


#: column headings of the free-station QA sections (each section has its own)
QA_POINT_HEADS = ["Point", "Used", "Across [mm]", "Along [mm]", "Height [mm]", 'Hz ["]', 'Zenith ["]', "Dist [mm]",
                  "|w| max", "Reason"]
QA_OVERLAP_HEADS = ["Old / new fix", "Stations", "dE [mm]", "dN [mm]", "dH [mm]", "Sigma E/N/H", "|d|/sigma",
                    "Tol./axis [mm]", "Verdict", "Reason"]
QA_FIX_HEADS = ["Point", "Time [s]", "", "", "", "", "", "", "", "Reason"]
QA_WIDTHS = [0.11, 0.06, 0.07, 0.07, 0.07, 0.10, 0.06, 0.06, 0.07, 0.33]


def _qa_rows(rep: SurveyReport) -> list[tuple[str, list[str], bool]]:
    """Rows of the free-station QA pages: (kind, cells, red), kind "title" (a section's title),
    "head" (its column headings) or "point" (a row of values)."""
    from trolley import units

    from survey.workbook import _field_only_rejections

    rec = rep.record
    out: list[tuple[str, list[str], bool]] = []
    arcsec = units.arcsec_to_rad(1.0)
    for st in rec.setups:
        dropped = [p.point for p in st.pointings if not p.used]
        out.append(("title", [f"Station {st.station}: E {st.E_m:.4f} N {st.N_m:.4f} H {st.H_m:.4f} m, sigma0 "
                              f"{st.sigma0:.2f} ({st.dof} dof), {'accepted' if st.accepted else 'not accepted'}, "
                              f"{sum(p.used for p in st.pointings)} points used"
                              + (f", dropped {', '.join(dropped)}" if dropped else "")
                              + "; residuals across / along / height of the line of sight"], False))
        out.append(("head", QA_POINT_HEADS, False))
        for p in st.pointings:
            out.append(("point", [p.point, "yes" if p.used else "dropped", _fmt(p.across_m * 1e3), _fmt(p.along_m * 1e3),
                                  _fmt(p.height_m * 1e3), _fmt(p.hz_rad / arcsec, 1), _fmt(p.zenith_rad / arcsec, 1),
                                  _fmt(p.distance_m * 1e3), _fmt(p.max_standardized, 1),
                                  p.reason if (p.flagged or not p.used) else "ok"], p.flagged or not p.used))
    out.append(("title", ["Overlap checks: one stop fixed from two stations, new minus old per axis; tolerance, "
                          "and sigma of the difference from both setups"], False))
    out.append(("head", QA_OVERLAP_HEADS, False))
    for o in rec.overlaps:
        out.append(("point", [f"{o.old_point} / {o.new_point}", f"{o.from_station}->{o.to_station}",
                              _fmt(o.dE_m * 1e3), _fmt(o.dN_m * 1e3), _fmt(o.dH_m * 1e3),
                              "/".join(_fmt(x * 1e3) for x in (o.sigma_dE_m, o.sigma_dN_m, o.sigma_dH_m))
                              if math.isfinite(o.sigma_dE_m) else "",
                              _fmt(o.max_d_over_sigma),
                              _fmt(o.tolerance_m * 1e3), "within" if o.within else "OUTSIDE", o.reason], not o.within))
    out.append(("title", ["Fixes rejected or undone"], False))
    out.append(("head", QA_FIX_HEADS, False))
    for f in sorted(list(_field_only_rejections(rep)) + [f for f in (rep.fixes or []) if not f.accepted],
                    key=lambda f: f.t_s):
        out.append(("point", [f.point, f"{f.t_s:.1f}", "", "", "", "", "", "", "", f.reason or "rejected"], True))
    return out


def qa_pages(rows: list[tuple[str, list[str], bool]], per_page: int = QA_ROWS) -> list[list[tuple[str, list[str], bool]]]:
    """The QA rows cut into pages of at most ``per_page`` rows. A page that starts inside a
    section starts with that section's column headings again; no page ends on a title or
    headings without a row below them."""
    pages: list[list] = [[]]
    head = None
    for row in rows:
        kind = row[0]
        if kind == "head":
            head = row
        page = pages[-1]
        # rows this one needs on the same page: a title its headings and a first row, headings a first row
        need = 3 if kind == "title" else 2 if kind == "head" else 1
        if len(page) + need > per_page and page:
            pages.append([] if kind != "point" or head is None else [head])
        pages[-1].append(row)
    return pages


def _qa(fig, chunk) -> None:
    rows = [cells if kind != "title" else [cells[0]] for kind, cells, _ in chunk]
    red = {i for i, (_, _, r) in enumerate(chunk) if r}
    bold = {i for i, (kind, _, _) in enumerate(chunk) if kind == "title"}
    subheads = {i for i, (kind, _, _) in enumerate(chunk) if kind == "head"}
    ax = fig.add_axes([0.05, 0.06, 0.9, 0.86])
    _table(ax, rows, None, QA_WIDTHS, red, fontsize=6.5, bold=bold, subheads=subheads)


def page_plan(rep: SurveyReport) -> list[tuple[str, callable]]:
    """The report's pages: (title, draw(fig)) in order."""
    plan: list[tuple[str, callable]] = [("Cover", lambda fig: _cover(fig, rep)),
                                        ("Summary", lambda fig: _summary(fig, rep))]
    s = rep.geometry.chainage_m
    marks = panel_marks(rep)
    k0, k1 = int(math.floor(s[0] / STRIP_M)), int(math.floor(s[-1] / STRIP_M))
    for k in range(k0, k1 + 1):
        a, b = max(k * STRIP_M, float(s[0])), min((k + 1) * STRIP_M, float(s[-1]))
        if b <= a:
            continue
        plan.append((f"Strip charts {km_label(rep.station(a), 0)} to {km_label(rep.station(b), 0)}",
                     lambda fig, a=a, b=b: _strip(fig, rep, a, b, marks)))
    numbered = list(enumerate(rep.defects, start=1))
    chunks = [numbered[i:i + DEFECT_ROWS] for i in range(0, len(numbered), DEFECT_ROWS)] or [[]]
    for j, chunk in enumerate(chunks, start=1):
        plan.append((f"Defects ({j}/{len(chunks)})", lambda fig, c=chunk: _defects(fig, rep, c)))
    plan.append(("Track quality per section", lambda fig: _quality(fig, rep)))
    if rep.record is None:
        plan.append(("Free-station QA", lambda fig: fig.text(
            0.05, 0.9, "No field record beside track.csv (a track processed outside a field session): station "
                       "setups and overlap checks not given.", fontsize=10)))
    else:
        chunks = qa_pages(_qa_rows(rep))
        for j, chunk in enumerate(chunks, start=1):
            plan.append((f"Free-station QA ({j}/{len(chunks)})", lambda fig, c=chunk: _qa(fig, c)))
    return plan


def write_pdf_report(path: Path, rep: SurveyReport) -> PdfReport:
    """Write the PDF report to ``path`` (all or nothing). Returns the path and the page titles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.backends.backend_pdf import PdfPages

    path = Path(path)
    plan = page_plan(rep)
    buf = io.BytesIO()
    with PdfPages(buf, metadata={"Title": f"Track survey report {rep.info.project}".strip(),
                                 "Creator": "trolley-survey"}) as pdf:
        for i, (title, draw) in enumerate(plan, start=1):
            fig = plt.figure(figsize=PAGE_SIZE_IN)
            try:
                draw(fig)
                _frame(fig, rep, title, i, len(plan))
                pdf.savefig(fig)
            finally:
                plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())
    return PdfReport(path=path, pages=tuple(t for t, _ in plan))


__all__ = ["PdfReport", "page_plan", "write_pdf_report"]
