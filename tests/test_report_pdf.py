"""The PDF report (survey/reportpdf.py, `trolley export --pdf`) and the PNG plots: pages as
planned, counted in the file itself; all or nothing."""
from __future__ import annotations

import math
import re

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

    from survey.plots import draw_panel, edge_zones, fix_chainages, panel_marks

    _, res = report
    rep = res.report
    fig, ax = plt.subplots()
    draw_panel(ax, rep, ["lateral_dev_m"], panel_marks(rep))
    assert ax.get_ylabel() == "Lateral dev [mm]\n+right"                  # quantity, unit, sign
    labels = ax.get_legend_handles_labels()[1]
    assert "±1σ" in labels and "CPIII fix" in labels
    plt.close(fig)
    # the fixes of fixes.csv stand at E 1000, N 5000: the start of the alignment (chainage 0)
    acc, rej = fix_chainages(rep)
    assert acc.size == 3 and np.all(acc == 0.0) and rej.size == 1   # the filter's reject; the field ones lie off this track
    # D3 (70-200 m) edge zones: 100 m from each end of the values
    s = rep.geometry.chainage_m
    v = rep.geometry.columns["align_D3_m"]
    z = edge_zones(s, v, "align_D3_m")
    ok = np.flatnonzero(np.isfinite(v))
    assert z == [(s[ok[0]], s[ok[0]] + 100.0), (s[ok[-1]] - 100.0, s[ok[-1]])]
    assert edge_zones(s, v, "lateral_dev_m") == []


def test_cli_pdf(tmp_path):
    from typer.testing import CliRunner

    from survey.cli import app

    out = _write_outputs(tmp_path / "o", with_design=False)
    r = CliRunner().invoke(app, ["export", str(out), "--pdf", str(tmp_path / "r.pdf")])
    assert r.exit_code == 0, r.output
    assert _pages_in(tmp_path / "r.pdf") == 2 + 1 + 1 + 1 + 1                # no field record: one QA page
    r = CliRunner().invoke(app, ["export", str(out), "--pdf", str(tmp_path / "nofolder" / "r.pdf")])
    assert r.exit_code == 2 and "does not exist" in r.output
