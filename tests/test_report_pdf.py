"""The PDF report (survey/reportpdf.py, `trolley export --pdf`) and the PNG plots: pages as
planned, counted in the file itself; all or nothing."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

from test_export_workbook import N, STEP, _write_outputs
from test_field_record import _store


def _pages_in(path) -> int:
    """Page objects of a PDF (matplotlib writes them uncompressed): /Type /Page, not /Pages."""
    return len(re.findall(rb"/Type\s*/Page(?![s\w])", path.read_bytes()))


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    from survey.export import export_outputs
    from survey.fieldrecord import field_record, write_field_record

    base = tmp_path_factory.mktemp("pdf")
    out = _write_outputs(base / "o")
    with _store(base) as st:
        write_field_record(out, field_record(st, "s1"))
    res = export_outputs(out, None, None, base / "plots", pdf=base / "report.pdf")
    return base, res


def test_pdf_pages_as_planned(report):
    from survey.reportpdf import DEFECT_ROWS

    base, res = report
    rep = res.report
    assert res.pdf == base / "report.pdf" and res.as_dict()["pdf"] == str(base / "report.pdf")
    km = math.floor((N - 1) * STEP / 1000.0) + 1                       # 500 m: one strip page
    defect_pages = max(1, math.ceil(len(rep.defects) / DEFECT_ROWS))
    # cover, summary, strips, defects, section quality, free-station QA (2 setups, 1 overlap, 3+1 rejected: 1 page)
    want = 2 + km + defect_pages + 1 + 1
    assert _pages_in(base / "report.pdf") == want
    text = (base / "report.pdf").read_bytes()
    assert b"%PDF-1." in text[:10] and text.rstrip().endswith(b"%%EOF")
    assert not list(base.glob(".report.pdf*"))                          # no temporary file left


def test_pdf_page_titles_and_a_survey_of_several_km(report, tmp_path):
    from dataclasses import replace

    import numpy as np

    from survey.reportpdf import page_plan

    _, res = report
    rep = res.report
    titles = [t for t, _ in page_plan(rep)]
    assert titles[:3] == ["Cover", "Summary", "Strip charts 0+000 to 0+499"]
    assert titles[-1] == "Free-station QA (1/1)" and "Track quality per section" in titles
    # the same survey shifted to 1+800: strips 1+800-2+000 and 2+000-2+299
    g = replace(rep.geometry, chainage_m=rep.geometry.chainage_m + 1800.0)
    strips = [t for t, _ in page_plan(replace(rep, geometry=g)) if t.startswith("Strip")]
    assert strips == ["Strip charts 1+800 to 2+000", "Strip charts 2+000 to 2+299"]


def test_plots_written_with_marks(report):
    base, res = report
    names = sorted(p.name for p in res.plots)
    assert "deviations.png" in names and "chords_lateral.png" in names and "level_bands.png" in names
    assert all(p.stat().st_size > 10_000 and p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in res.plots)


def test_panel_labels_marks_and_edge_zones(report):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from survey.plots import draw_panel, edge_zones, panel_marks
    from survey.track_table import fix_chainages

    _, res = report
    rep = res.report
    fig, ax = plt.subplots()
    draw_panel(ax, rep, ["lateral_dev_m"], panel_marks(rep))
    assert ax.get_ylabel() == "Lateral dev [mm]\n+right"                  # quantity, unit, sign
    labels = ax.get_legend_handles_labels()[1]
    assert "±1σ" in labels and "CPIII fix" in labels
    plt.close(fig)
    # the fixes of fixes.csv stand at E 1000, N 5000: the start of the alignment (chainage 0)
    acc, rej = fix_chainages(rep.geometry, rep.fixes, rep.record)
    assert acc.size == 3 and np.all(acc == 0.0) and rej.size == 1   # the filter's reject; the field ones lie off this track
    # D3 (70-200 m) edge zones: the 200 m at each end of the deviations the band leaves empty
    s = rep.geometry.chainage_m
    v = rep.geometry.columns["align_D3_m"]
    dev = rep.geometry.columns["lateral_dev_m"]
    z = edge_zones(s, v, dev, "align_D3_m")
    ok, has = np.flatnonzero(np.isfinite(v)), np.flatnonzero(np.isfinite(dev))
    assert ok.size and s[ok[0]] - s[has[0]] == pytest.approx(200.0) and s[has[-1]] - s[ok[-1]] == pytest.approx(200.0)
    assert z == [(s[has[0]], s[ok[0] - 1]), (s[ok[-1] + 1], s[has[-1]])]
    assert edge_zones(s, v, dev, "lateral_dev_m") == [] and edge_zones(s, v, None, "align_D3_m") == []


def test_cli_pdf(tmp_path):
    from typer.testing import CliRunner

    from survey.cli import app

    out = _write_outputs(tmp_path / "o", with_design=False)
    r = CliRunner().invoke(app, ["export", str(out), "--pdf", str(tmp_path / "r.pdf")])
    assert r.exit_code == 0, r.output
    assert _pages_in(tmp_path / "r.pdf") == 2 + 1 + 1 + 1 + 1                # no field record: one QA page
    r = CliRunner().invoke(app, ["export", str(out), "--pdf", str(tmp_path / "nofolder" / "r.pdf")])
    assert r.exit_code == 2 and "does not exist" in r.output


def test_table_rows_stay_on_their_shading_to_the_foot_of_the_page():
    """Every row of a long table is drawn at its own height: the text of each red row lies inside
    its red band (one multi-line text per column drifted about a line by row 30), and the columns
    of a row start at the same character in every row (monospaced, padded)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from survey.reportpdf import PAGE_SIZE_IN, TABLE_FONT, _table

    fig = plt.figure(figsize=PAGE_SIZE_IN)
    ax = fig.add_axes([0.05, 0.06, 0.9, 0.86])
    rows = [[str(i), f"parameter {'x' * (i % 7)}", f"{i * 1.25:.2f}", "mm"] for i in range(56)]
    red = set(range(0, 56, 2))
    _table(ax, rows, ["#", "Parameter", "Peak", "Unit"], [0.1, 0.5, 0.2, 0.2], red, fontsize=7.0)
    renderer = fig.canvas.get_renderer()
    texts = [t for t in fig.texts if t.get_fontfamily()[0] == TABLE_FONT]
    assert len(texts) == 1 + len(rows)                                   # header + one text per row
    bands = sorted((p.get_window_extent(renderer) for p in fig.patches), key=lambda b: -b.y0)
    red_bands = bands[1:]                                                # the first is the header's
    assert len(red_bands) == len(red)
    for i, band in zip(sorted(red), red_bands):
        box = texts[1 + i].get_window_extent(renderer)
        assert band.y0 < 0.5 * (box.y0 + box.y1) < band.y1, i
        assert box.y0 > 0.06 * fig.bbox.height                           # still above the page foot
    starts = {texts[1 + i].get_text().index(f"{i * 1.25:.2f}") for i in range(len(rows))}
    assert len(starts) == 1                                              # the Peak column lines up
    plt.close(fig)


def test_qa_sections_have_their_own_headings(report):
    """Overlap checks sit under dE / dN / dH headings (not the residuals' across / along / height),
    the rejected fixes under their own; a page that starts inside a section repeats its headings."""
    from survey.reportpdf import QA_FIX_HEADS, QA_OVERLAP_HEADS, QA_POINT_HEADS, _qa_rows, qa_pages

    _, res = report
    rows = _qa_rows(res.report)
    kinds = [k for k, _, _ in rows]
    i = next(j for j, (k, c, _) in enumerate(rows) if k == "title" and c[0].startswith("Overlap checks"))
    assert rows[i + 1] == ("head", QA_OVERLAP_HEADS, False)
    assert rows[i + 1][1][2:5] == ["dE [mm]", "dN [mm]", "dH [mm]"]
    over = rows[i + 2]
    assert over[0] == "point" and " / " in over[1][0]
    o = res.report.record.overlaps[0]
    assert over[1][2:5] == [f"{x * 1e3:.2f}" for x in (o.dE_m, o.dN_m, o.dH_m)]
    assert over[1][7:9] == [f"{o.tolerance_m * 1e3:.2f}", "within" if o.within else "OUTSIDE"]
    # the difference's sigma per axis (0.6 mm on each fix: 0.85 mm) and the largest |d| / sigma (3 mm in H)
    assert rows[i + 1][1][5:7] == ["Sigma E/N/H", "|d|/sigma"]
    assert over[1][5:7] == ["0.85/0.85/0.85", f"{3.0 / np.sqrt(0.72):.2f}"]
    j = next(j for j, (k, c, _) in enumerate(rows) if k == "title" and c[0] == "Fixes rejected or undone")
    assert rows[j + 1] == ("head", QA_FIX_HEADS, False)
    assert all(rows[k - 1][0] in ("head", "point") for k in range(len(rows)) if kinds[k] == "point")
    for per_page in (4, 5, 7):
        pages = qa_pages(rows, per_page)
        assert all(0 < len(p) <= per_page for p in pages)
        for p in pages:
            assert p[-1][0] == "point" or p is pages[-1] and p[-1][1] == QA_FIX_HEADS
            assert p[0][0] != "point", "a page starts with a value row, without headings"
        body = [r for p in pages for r in p if r[0] != "head"]
        assert body == [r for r in rows if r[0] != "head"]               # nothing lost, nothing doubled
        continued = [p for p in pages[1:] if p[0][0] == "head"]
        assert continued and all(p[0][1] in (QA_POINT_HEADS, QA_OVERLAP_HEADS, QA_FIX_HEADS) for p in continued)


def test_qa_pages_hand_cut():
    """Pages of four rows, cut by hand: a section continued on a new page repeats its headings;
    a title never ends a page without its headings and first row."""
    from survey.reportpdf import qa_pages

    rows = ([("title", ["S1"], False), ("head", ["P"], False)] + [("point", [f"p{i}"], False) for i in range(5)]
            + [("title", ["Ov"], False), ("head", ["dE"], False), ("point", ["o1"], False),
               ("title", ["Fx"], False), ("head", ["F"], False)] + [("point", [f"f{i}"], True) for i in range(3)])
    got = [[r[1][0] for r in p] for p in qa_pages(rows, 4)]
    assert got == [["S1", "P", "p0", "p1"], ["P", "p2", "p3", "p4"], ["Ov", "dE", "o1"], ["Fx", "F", "f0", "f1"],
                   ["F", "f2"]]


def test_chord_magnitude_cycles_with_the_spacing_and_the_plot_draws_its_maximum(report):
    """The 30 m / 5 m check's magnitude cycles every 5 m by its definition (hand case: a single
    1 mm ramp over 2 m); the panel's line is the maximum over one spacing, which is flat there,
    and the per-station values are drawn thin beneath it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from survey.plots import chord_envelope, chord_spacing_m, draw_panel, panel_marks
    from trolley.trackgeometry import long_chord_check

    step = 0.625
    s = np.arange(0.0, 200.0, step)
    ramp = np.clip((s - 100.0) / 2.0, 0.0, 1.0) * 1e-3
    v = np.abs(long_chord_check(ramp, 30.0, 5.0, step))
    mid = v[np.searchsorted(s, 90.0):np.searchsorted(s, 110.0)]
    assert mid.max() - mid.min() > 0.3e-3                                # 0.83 vs 0.46 mm: the check itself
    np.testing.assert_allclose(mid[:8], mid[8:16], atol=1e-12)            # period: 8 stations = 5 m
    env = chord_envelope(v, 5.0, step)[np.searchsorted(s, 90.0):np.searchsorted(s, 110.0)]
    np.testing.assert_allclose(env, mid.max(), atol=1e-12)               # flat at the worst phase
    assert np.isnan(chord_envelope(v, 5.0, step)[np.isnan(v)]).all()
    _, res = report
    rep = res.report
    assert chord_spacing_m(rep, "chord30_5_lat_m") == 5.0 and chord_spacing_m(rep, "chord300_150_lat_m") is None
    fig, ax = plt.subplots()
    draw_panel(ax, rep, ["chord30_5_lat_m"], panel_marks(rep))
    raw, line = ax.get_lines()[:2]
    assert raw.get_linewidth() < line.get_linewidth() and line.get_label().endswith("max over 5 m")
    a, b = raw.get_ydata(), line.get_ydata()
    ok = np.isfinite(a)
    assert np.all(b[ok] >= a[ok]) and np.nanmax(b) == pytest.approx(np.nanmax(a))
    plt.close(fig)


def test_section_rows_cover_some_track(report):
    """Every section-quality row (sheet and PDF) spans track; a survey ending on a section limit
    gets no empty last row (it touches the next section in one station only)."""
    from dataclasses import replace

    import numpy as np

    from survey.workbook import section_table

    _, res = report
    for rep in (res.report, replace(res.report, geometry=_cut_at_section_limit(res.report.geometry))):
        s = rep.geometry.chainage_m
        keys, quals = section_table(rep)
        q0 = quals[0]
        assert q0.start_m.size >= 1
        assert np.all(np.maximum(q0.start_m, s[0]) < np.minimum(q0.end_m, s[-1]))
        assert all(q.start_m.size == q0.start_m.size for q in quals)


def _cut_at_section_limit(g):
    """The geometry up to and including the station on the first 200 m limit after its start."""
    from dataclasses import replace

    import numpy as np

    s = g.chainage_m
    limit = (np.floor(s[0] / 200.0) + 1) * 200.0
    n = int(np.searchsorted(s, limit + 1e-9))
    assert abs(s[n - 1] - limit) < 1e-9, "the station grid has a station on the limit"
    return replace(g, chainage_m=s[:n], columns={k: v[:n] for k, v in g.columns.items()})
