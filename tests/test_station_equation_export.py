"""End to end on a design with a station equation: simulate, process, export.

The design (tests/data/station_equation.xml) runs from internal station 1000 to 1750 with the
equation 1+300.000 back = 2+300.000 ahead at internal station 1300 (a forward jump of 1000 m).
The simulated survey covers internal stations 1200 to 1400, i.e. drawing stations 1+200 to
1+300 and 2+300 to 2+400. What the client sees (docs/conventions.md, "Design geometry"): every
chainage is the drawing stationing; geometry runs along the distance (track.csv distance_m).
"""
from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from survey.cli import app
from track_sheet import track_table

DATA = Path(__file__).resolve().parent / "data"
EQ_INTERNAL, BACK, AHEAD = 1300.0, 1300.0, 2300.0
#: the injected gauge defect: +8 mm over the odometer distance 180.0-181.0 m from the start
#: (internal station 1380-1381, drawing station 2+380-2+381)
DEFECT_FROM_M, DEFECT_MM = 180.0, 8.0

PROJECT_TOML = """name = "equation"
[site]
latitude_deg = 50.0
height_m = 100.0
[design]
alignment = "station_equation.xml"
[imu]
preset = "rlg"
[simulation]
start_chainage_m = 1200.0
length_m = 200.0
fix_spacing_m = 50.0
stop_s = 10.0
static_s = 30.0
speed_m_s = 1.0
imu_rate_hz = 100.0
seed = 3
"""


def _run(args):
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, (args[0], r.stdout, r.stderr)
    return r


def _inject_gauge_defect(session: Path) -> None:
    """Add DEFECT_MM to the raw gauge readings taken while the odometer is 1 m past DEFECT_FROM_M."""
    odo = np.loadtxt(session / "odometer.csv", delimiter=",", skiprows=1)
    lines = (session / "gauge.csv").read_text(encoding="utf-8").splitlines()
    g = np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]])
    dist = np.interp(g[:, 0], odo[:, 0], odo[:, 1])
    hit = (dist >= DEFECT_FROM_M) & (dist <= DEFECT_FROM_M + 1.0)
    assert 5 <= hit.sum() <= 20
    g[hit, 1] += DEFECT_MM * 1e-3
    (session / "gauge.csv").write_text(
        lines[0] + "\n" + "".join(f"{t!r},{v!r}\n" for t, v in g.tolist()), encoding="utf-8")


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    root = tmp_path_factory.mktemp("equation")
    proj = root / "project"
    proj.mkdir()
    (proj / "project.toml").write_text(PROJECT_TOML, encoding="utf-8")
    shutil.copy(DATA / "station_equation.xml", proj / "station_equation.xml")
    _run(["simulate", "--out", str(root / "session"), "--project", str(proj)])
    _inject_gauge_defect(root / "session")
    _run(["process", str(root / "session"), "--out", str(root / "processed")])
    _run(["export", str(root / "processed"), "--xlsx", str(root / "sheet.xlsx"), "--csv", str(root / "track_out.csv")])
    return root


def _columns(path: Path) -> dict[str, np.ndarray]:
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    return {h: np.array([float(r[j]) if r[j] else np.nan for r in rows[1:]]) for j, h in enumerate(rows[0])}


@pytest.mark.parametrize("name", ["processed/track.csv", "track_out.csv"])
def test_chainage_jumps_at_the_equation_and_distance_does_not(exported, name):
    cols = _columns(exported / name)
    c, d = cols["chainage_m"], cols["distance_m"]
    step = np.diff(d)
    assert np.allclose(step, step[0], atol=1e-6) and step[0] > 0          # distance: uniform, no jump
    jump = np.diff(c) - step
    k = int(np.argmax(np.abs(jump)))
    assert jump[k] == pytest.approx(AHEAD - BACK, abs=1e-6)               # one jump of +1000 m ...
    assert np.allclose(np.delete(jump, k), 0.0, atol=1e-6)                # ... and nowhere else
    assert d[k] < EQ_INTERNAL <= d[k + 1]                                 # where the equation is
    np.testing.assert_allclose(c, np.where(d < EQ_INTERNAL, d, d - EQ_INTERNAL + AHEAD), atol=1e-6)


def test_workbook_shows_the_drawing_stationing(exported):
    import openpyxl

    wb = openpyxl.load_workbook(exported / "sheet.xlsx")
    ws = wb["Track"]
    top, head = track_table(ws)
    assert head[0] == "Chainage [m]" and head[1] == "Station [km+m]" and head[-1] == "Station equation"
    chain = {}
    note_rows = []
    for r in range(top + 1, ws.max_row + 1):
        chain[r] = ws.cell(r, 1).value
        assert ws.cell(r, 2).value == chain[r]
        if ws.cell(r, len(head)).value:
            note_rows.append(r)
    d = _columns(exported / "processed" / "track.csv")["distance_m"]
    row_of = {round(float(x), 6): i + top + 1 for i, x in enumerate(d)}
    # hand-chosen points: internal station -> drawing station
    for internal, drawing in [(1200.0, 1200.0), (1250.0, 1250.0), (1299.375, 1299.375), (1300.0, 2300.0),
                              (1350.0, 2350.0), (1400.0, 2400.0)]:
        assert chain[row_of[internal]] == pytest.approx(drawing, abs=1e-9), internal
    assert note_rows == [row_of[1300.0]]
    assert ws.cell(note_rows[0], len(head)).value == \
        "station equation: 1+300.000 back = 2+300.000 ahead (jump +1000.000 m)"
    summary = {row[0]: row[1] for row in wb["Summary"].iter_rows(values_only=True) if row[0]}
    assert summary["Chainage from [m]"] == pytest.approx(1200.0)
    assert summary["Chainage to [m]"] == pytest.approx(2400.0)
    assert summary["Station equation"].startswith("station equation: 1+300.000 back = 2+300.000 ahead")
    printed = [row[0] for row in wb["Track print"].iter_rows(values_only=True)]
    i = printed.index("station equation: 1+300.000 back = 2+300.000 ahead (jump +1000.000 m)")
    assert printed[i - 1] == pytest.approx(1295.0) and printed[i + 1] == pytest.approx(2300.0)


def test_injected_defect_is_listed_at_its_drawing_station(exported):
    import openpyxl

    ws = openpyxl.load_workbook(exported / "sheet.xlsx")["Defects"]
    rows = list(ws.iter_rows(values_only=True))
    head = next(i for i, r in enumerate(rows) if r[0] == "#")
    ours = [r for r in rows[head + 1:] if isinstance(r[0], int) and str(r[1]).startswith("Gauge dev")
            and r[7] is not None and r[7] > DEFECT_MM - 1.0]
    assert len(ours) == 1, rows[head + 1:]
    r = ours[0]
    # the odometer distance 180 m from the start (internal 1380) is drawing station 2+380; the
    # odometer scale error and the 0.625 m station step allow +-1 m
    assert AHEAD + 80.0 - 1.0 <= r[2] <= r[3] <= AHEAD + 81.0 + 1.0
    assert r[4] == r[2] and r[5] == r[3]                     # the km+m columns: the same stations
    assert r[6] == pytest.approx(r[3] - r[2] + 0.625)       # the length runs along the distance


def test_export_without_the_design_takes_the_stationing_from_track_csv(exported, tmp_path):
    """track.csv alone (no summary.json, no design): the chainages shown are still its chainage_m."""
    shutil.copy(exported / "processed" / "track.csv", tmp_path / "track.csv")
    out = tmp_path / "out.csv"
    r = _run(["export", str(tmp_path / "track.csv"), "--csv", str(out), "--json"])
    assert "jumps against distance_m" in r.stdout
    src, got = _columns(tmp_path / "track.csv"), _columns(out)
    np.testing.assert_allclose(got["chainage_m"], src["chainage_m"], atol=1e-9)
    np.testing.assert_allclose(got["distance_m"], src["distance_m"], atol=1e-9)


# stationing_of_track: hand cases (distance 1296..1304 every 1 m), then a round trip
D = 1296.0 + np.arange(9.0)


@pytest.mark.parametrize("chainage, equations", [
    (D.copy(), []),
    (np.where(D < 1300, D, D + 1000.0), [(1300.0, 2300.0, True)]),                  # forward jump
    (np.where(D < 1300, D, D - 50.0), [(1300.0, 1250.0, True)]),                    # backward jump
    (np.where(D < 1300, D, 5000.0 - (D - 1300.0)), [(1300.0, 5000.0, False)]),      # decreasing ahead
    (np.where(D <= 1300, D, 1300.0 - (D - 1300.0)), [(1300.0, 1300.0, False)]),     # turns without a jump
    (D + 100.0, [(1296.0, 1396.0, True)]),                                          # renumbered start
])
def test_stationing_of_track_by_hand(chainage, equations):
    from survey.track_reader import stationing_of_track

    st = stationing_of_track(D, chainage)
    if not equations:
        assert st is None
        return
    assert [(e.internal_m, e.ahead_m, e.increasing) for e in st.equations] == equations
    np.testing.assert_allclose(st.station(D), chainage, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(st_=st.data())
def test_stationing_of_track_reproduces_every_station(st_):
    """Any stationing sampled on a grid comes back at every sample (two regions may merge when an
    equation continues the stationing, and equations between two samples move to the later one)."""
    from trolley.stationing import StationEquation, Stationing

    from survey.track_reader import stationing_of_track

    step = st_.draw(st.sampled_from([0.25, 0.5, 0.625, 1.0]))
    n = st_.draw(st.integers(3, 60))
    d = 1000.0 + step * np.arange(n)
    at = sorted(set(st_.draw(st.lists(st.floats(d[0], d[-1] - 1e-3), max_size=4))))
    eqs = [StationEquation(a, st_.draw(st.floats(-5000.0, 5000.0).map(lambda x: round(x, 3))), None,
                           st_.draw(st.booleans())) for a in at]
    true = Stationing(d[0], d[-1] + step, eqs)
    c = np.round(true.station(d), 6)      # as track.csv writes it
    got = stationing_of_track(d, c)
    np.testing.assert_allclose(c if got is None else got.station(d), c, atol=1e-6)


def test_plots_and_pdf_label_the_drawing_stationing(exported, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from survey.export import build_report
    from survey.plots import km_axis
    from survey.reportpdf import page_plan, write_pdf_report

    rep, _ = build_report(exported / "processed")
    fig, (top, bottom) = plt.subplots(2, 1, sharex=True)
    top.set_xlim(1280.0, 1320.0)
    km_axis(bottom, rep)
    fmt = bottom.xaxis.get_major_formatter()
    assert fmt(1290.0, 0) == "1+290.0" and fmt(1310.0, 0) == "2+310.0"   # the axis runs along the distance
    assert bottom.get_xlabel() == "chainage [km+m] (drawing stationing)"
    for ax in (top, bottom):      # the equation line on every panel, its label on the top one
        assert [tuple(ln.get_xdata()) for ln in ax.get_lines()] == [(1300.0, 1300.0)]
    assert [t.get_text() for t in top.texts] == [" 1+300.000 back = 2+300.000 ahead"] and not bottom.texts
    plt.close(fig)
    assert "Strip charts 1+200 to 2+400" in [t for t, _ in page_plan(rep)]
    assert write_pdf_report(tmp_path / "r.pdf", rep).path.stat().st_size > 0
