"""Stations outside the outermost fixes: their deviations from the design are shown, not checked.

A session ended 1140 m after its last fix had sigmas up to 495 mm there and 38 "defects" that
were the dead reckoning's drift (bug hunt 2026-11-27). Beyond the first and the last fix the
export now checks only the relative parameters; the absolute ones (lateral and vertical
deviation, slew, lift) are left out of the defects, the statistics and the Track sheet's red
cells, and a note says where and with which sigma.
"""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from test_export_workbook import STEP, _write_outputs
from trolley.trackgeometry import fixed_span, nearest_stations


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 60), st.integers(0, 12), st.floats(0.2, 5.0), st.integers(0, 2**32 - 1))
def test_nearest_stations_is_the_brute_force_nearest_within_the_distance(n, m, limit, seed):
    rng = np.random.default_rng(seed)
    E = 5e5 + rng.uniform(-50, 50, n)          # grid coordinates: the tree works relative to one station
    N = 3.1e6 + rng.uniform(-50, 50, n)
    E[rng.random(n) < 0.1] = np.nan             # stations in a gap
    pE, pN = 5e5 + rng.uniform(-60, 60, m), 3.1e6 + rng.uniform(-60, 60, m)
    got = nearest_stations(E, N, pE, pN, limit)
    d2 = (np.nan_to_num(E, nan=np.inf)[None, :] - pE[:, None]) ** 2 + (np.nan_to_num(N, nan=np.inf)[None, :] - pN[:, None]) ** 2
    for k in range(m):
        best = int(np.argmin(d2[k])) if np.isfinite(d2[k]).any() else -1
        if best < 0 or np.sqrt(d2[k, best]) > limit:
            assert got[k] == -1
        else:  # a tie of two stations at one distance may take either
            assert got[k] >= 0 and d2[k, got[k]] == pytest.approx(d2[k, best], rel=1e-9, abs=1e-12)


def test_fixed_span_by_hand():
    s = np.arange(11) * 10.0
    assert fixed_span(s, np.array([30.0, 70.0, 50.0])).tolist() == [False] * 3 + [True] * 5 + [False] * 3
    assert not fixed_span(s, np.array([np.nan])).any()
    assert fixed_span(s, np.array([40.0])).tolist() == [x == 40.0 for x in s]   # one fix: no span


def _outputs_with_fixes_at(out, fix_chainages_m, extra_lateral_m):
    """The synthetic survey of test_export_workbook with fixes on the track at the given chainages
    and extra lateral deviation {chainage_m: metres} over 2 m from each chainage."""
    out = _write_outputs(out)
    t = pd.read_csv(out / "track.csv")
    heading = np.arctan2(np.gradient(t.E_m.to_numpy()), np.gradient(t.N_m.to_numpy()))
    for at, dev in extra_lateral_m.items():
        # moved to the right (the export measures the deviation from E, N and the design)
        sel = ((t.chainage_m >= at) & (t.chainage_m <= at + 2.0)).to_numpy()
        t.loc[sel, "E_m"] += dev * np.cos(heading[sel])
        t.loc[sel, "N_m"] -= dev * np.sin(heading[sel])
        t.loc[sel, "lateral_dev_mm"] += dev * 1e3
    t.to_csv(out / "track.csv", index=False, float_format="%.6f", na_rep="")
    i = np.searchsorted(t.chainage_m.to_numpy(), fix_chainages_m)
    n = len(fix_chainages_m)
    pd.DataFrame({"t_s": 60.0 * np.arange(n), "point": [f"FIX{k + 1:03d}" for k in range(n)],
                  "E_m": t.E_m.to_numpy()[i] + 0.3, "N_m": t.N_m.to_numpy()[i] - 0.2, "H_m": 51.0,
                  "innov_E_mm": 0.1, "innov_N_mm": 0.1, "innov_H_mm": 0.1, "nis": 1.0, "accepted": 1,
                  "reason": ""}).to_csv(out / "fixes.csv", index=False)
    return out


def test_deviations_outside_the_outermost_fixes_are_shown_not_checked(tmp_path):
    from openpyxl import load_workbook

    from survey.export import UNFIXED_NOTE, export_outputs

    # fixes at 50, 150 and 300 m; a 15 mm lateral step at 250 m (between fixes: a defect), at 20 m
    # (before the first) and at 400 m (beyond the last): not checked there
    out = _outputs_with_fixes_at(tmp_path / "o", [50.0, 150.0, 300.0], {20.0: 0.015, 250.0: 0.015, 400.0: 0.040})
    res = export_outputs(out, tmp_path / "s.xlsx", None, None)
    rep = res.report
    lateral = [d for d in rep.defects if d.column == "lateral_dev_m"]
    assert [(d.start_chainage_m, d.end_chainage_m) for d in lateral] == [(250.0, 251.875)]
    s = rep.geometry.chainage_m
    assert np.array_equal(rep.absolute_checked, (s >= 50.0) & (s <= 300.0))
    # the statistics count the checked stations only; the Track values stay as they are
    assert rep.stats["lateral_dev_m"].count == int(((s >= 50.0) & (s <= 300.0)).sum()) == 401
    assert np.nanmax(rep.geometry.columns["lateral_dev_m"][s > 300.0]) > 0.039   # the 40 mm step, shown
    note = next(n for n in rep.notes if n.startswith(UNFIXED_NOTE))
    sig = 1e3 * rep.geometry.columns["sigma_lateral_m"]
    assert (f"0.000-49.375 m, before the first fix used (50.000 m; sigma lateral up to {sig[s < 50].max():.1f} mm"
            in note)
    assert f"300.625-{s[-1]:.3f} m, beyond the last fix used (300.000 m;" in note
    # the Track sheet's red cells: the lateral deviation column is formatted on the checked rows only
    from survey.workbook import TRACK_FIRST_ROW

    ws = load_workbook(tmp_path / "s.xlsx")["Track"]
    col = next(c.column_letter for c in ws[TRACK_FIRST_ROW - 1] if c.value and str(c.value).startswith("Lateral dev"))
    ranges = [str(r.sqref) for r in ws.conditional_formatting if str(r.sqref).startswith(col)]
    first = TRACK_FIRST_ROW + int(np.flatnonzero(s >= 50.0)[0])
    assert sorted(ranges) == sorted([f"{col}{TRACK_FIRST_ROW}:{col}{first - 1}", f"{col}{first}:{col}{first + 400}",
                                     f"{col}{first + 401}:{col}{TRACK_FIRST_ROW + s.size - 1}"])
    rules = {str(r.sqref): r.rules[0] for r in ws.conditional_formatting if str(r.sqref).startswith(col)}
    assert rules[f"{col}{TRACK_FIRST_ROW}:{col}{first - 1}"].dxf.font.i           # grey italic: not checked
    assert rules[f"{col}{first}:{col}{first + 400}"].dxf.fill is not None          # red beyond the limit
    # the PDF's summary page says it too (the client signs the PDF)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from survey.reportpdf import _summary

    fig = plt.figure()
    _summary(fig, rep)
    shown = " ".join(" ".join(t.get_text().split()) for t in fig.texts)
    plt.close(fig)
    # the deviation panel's y range follows the checked stations (1.25 x their largest value):
    # the 40 mm beyond the last fix runs off it
    from survey.plots import draw_panel, panel_marks

    fig, ax = plt.subplots()
    draw_panel(ax, rep, ["lateral_dev_m"], panel_marks(rep))
    inside = rep.columns[[c.key for c in rep.columns].index("lateral_dev_m")].display(
        rep.geometry.columns["lateral_dev_m"][rep.absolute_checked])
    top = ax.get_ylim()[1]
    assert top == pytest.approx(1.25 * np.nanmax(np.abs(inside)), rel=1e-9) and top < 25.0
    plt.close(fig)
    assert "Note: deviations from the design not checked at stations 0.000-49.375 m, before the first fix" in shown
    # a note listing many gaps takes at most 4 lines: it took the page, the statistics table had a
    # negative height and no PDF was written (ValueError: Width and height ... must be non-negative)
    rep.notes.append("track.csv has no stations in " + ", ".join(f"{10 * i:.3f}-{10 * i + 5:.3f} m" for i in range(300)))
    fig = plt.figure()
    _summary(fig, rep)
    gaps = [t.get_text() for t in fig.texts if "no stations in" in t.get_text()]
    table = fig.axes[-1].get_position()
    plt.close(fig)
    assert len(gaps) == 1 and table.height > 0.4


def test_every_station_is_checked_between_fixes_at_both_ends_and_without_fixes_csv(tmp_path):
    from survey.export import UNFIXED_NOTE, export_outputs

    out = _outputs_with_fixes_at(tmp_path / "o", [0.0, 250.0, 499.375], {400.0: 0.015})
    rep = export_outputs(out, None, None, None).report
    assert rep.absolute_checked is None and not any(n.startswith(UNFIXED_NOTE) for n in rep.notes)
    assert [d.start_chainage_m for d in rep.defects if d.column == "lateral_dev_m"] == [400.0]
    # no fixes.csv: nothing tells the span, every station is checked as before
    (out / "fixes.csv").unlink()
    rep = export_outputs(out, None, None, None).report
    assert rep.absolute_checked is None
    assert [d.start_chainage_m for d in rep.defects if d.column == "lateral_dev_m"] == [400.0]


def test_the_command_prints_the_note_before_its_verdict(tmp_path):
    from typer.testing import CliRunner

    from survey.cli import app

    out = _outputs_with_fixes_at(tmp_path / "o", [0.0, 100.0], {400.0: 0.015})
    r = CliRunner().invoke(app, ["export", str(out), "--fail-on-defects"])
    text = " ".join(r.output.split())
    assert "note: deviations from the design not checked at stations 100.625-499.375 m, beyond the last fix" in text
    assert text.index("note: deviations") < text.index("stations, tolerances")


def test_a_pass_with_stations_beyond_the_fixes_does_not_say_no_value_is_beyond_tolerance(tmp_path):
    """The PDF's cover and the Defects sheet said "no value beyond tolerance" of a PASS with
    stations beyond the last fix, whose deviations from the design were not checked (the client
    signs the cover; bug hunt 2026-11-27's 1140 m beyond the last fix had 38 such values)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from survey.export import build_report
    from survey.reportpdf import _cover

    out = _outputs_with_fixes_at(tmp_path / "o", [0.0, 100.0], {})
    rep, _ = build_report(out / "track.csv", tolerances="en13848_5_alert")
    assert rep.passed and rep.absolute_checked is not None
    fig = plt.figure(figsize=(11.69, 8.27))   # A4 landscape, as the report
    _cover(fig, rep)
    shown = " ".join(t.get_text() for t in fig.texts)
    fig.canvas.draw()
    right = max(t.get_window_extent().x1 for t in fig.texts) / fig.bbox.width
    plt.close(fig)
    assert "PASS: no checked value beyond tolerance (not every value was checked: see the summary's notes)" in shown
    assert right < 0.97    # on the page
    assert "no value beyond tolerance" not in shown.replace("no checked value", "")
    (out / "fixes.csv").unlink()   # every station checked: as before
    rep, _ = build_report(out / "track.csv", tolerances="en13848_5_alert")
    assert rep.absolute_checked is None and rep.no_defects_text == "no value beyond tolerance"
