"""LandXML as design tools write it (tests/data/*.xml, written by make_landxml_fixtures.py):
several alignments, Feature and vendor extensions, station equations, feet, direction breaks
at joins, zero-length elements, overlapping vertical curves, a wrong declared length and a cant
station beyond the end. Every position is checked against a hand computation of the base
geometry (a 250 m straight on bearing 60 deg, a 200 m arc of radius 800 m to the right, a
300 m straight; start station 1000; coordinates in the files rounded to 0.1 mm)."""
from __future__ import annotations

import json

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from trolley import units
from trolley.alignment import HorizontalAlignment
from trolley.landxml import AlignmentChoiceError, LandXmlError, alignment_names, read_landxml
from trolley.stationing import StationEquation, StationNotFound, Stationing

DATA = Path(__file__).resolve().parent / "data"
N0, E0, B0 = 5_600_000.0, 400_000.0, math.radians(60.0)
L1, R, LA, L2 = 250.0, 800.0, 200.0, 300.0
#: positions from coordinates rounded to 0.1 mm: a few tenths of a mm
POS_TOL_M = 3e-4


def text(name: str) -> str:
    return (DATA / name).read_text(encoding="utf-8")


def hand_position(s: float, breaks: tuple[float, float] = (0.0, 0.0), e0: float = E0) -> tuple[float, float]:
    """(E, N) of the base geometry at station s, each element from its own start and direction."""
    b = B0
    a = complex(N0 + L1 * math.cos(b), e0 + L1 * math.sin(b))
    if s <= 1250.0:
        d = s - 1000.0
        z = complex(N0 + d * math.cos(b), e0 + d * math.sin(b))
        return z.imag, z.real
    b_arc = b + breaks[0]
    c = a + R * complex(math.cos(b_arc + math.pi / 2), math.sin(b_arc + math.pi / 2))
    if s <= 1450.0:
        phi = b_arc - math.pi / 2 + (s - 1250.0) / R
        z = c + R * complex(math.cos(phi), math.sin(phi))
        return z.imag, z.real
    phi = b_arc - math.pi / 2 + LA / R
    dz = c + R * complex(math.cos(phi), math.sin(phi))
    b2 = b_arc + LA / R + breaks[1]
    z = dz + (s - 1450.0) * complex(math.cos(b2), math.sin(b2))
    return z.imag, z.real


def assert_at(al, s: float, expected: tuple[float, float], tol: float = POS_TOL_M) -> float:
    p = al.evaluate(s)
    miss = math.hypot(float(p.E_m) - expected[0], float(p.N_m) - expected[1])
    assert miss < tol, (s, miss)
    return miss


# --------------------------------------------------------------------------------------------
def test_several_alignments_listed_and_chosen_by_name():
    t = text("several_alignments.xml")
    assert alignment_names(t) == ["Gleis 1", "Gleis 2", "Abstellgleis 3"]
    with pytest.raises(AlignmentChoiceError) as info:
        read_landxml(t)
    assert info.value.names == ["Gleis 1", "Gleis 2", "Abstellgleis 3"]
    assert "3 alignments" in str(info.value) and "'Abstellgleis 3'" in str(info.value)
    with pytest.raises(AlignmentChoiceError, match="no <Alignment name='Gleis 9'>"):
        read_landxml(t, "Gleis 9")
    g1, g2 = read_landxml(t, "Gleis 1").alignment, read_landxml(t, "Gleis 2").alignment
    for s in (1100.0, 1350.0, 1600.0):
        assert_at(g1, s, hand_position(s))
        assert_at(g2, s, hand_position(s, e0=E0 - 4.5))
    siding = read_landxml(t, "Abstellgleis 3").alignment
    assert siding.name == "Abstellgleis 3" and siding.end_chainage_m == pytest.approx(120.0, abs=1e-9)
    assert float(siding.evaluate(60.0).E_m) == pytest.approx(E0 + 60.0, abs=1e-9)
    # two alignments of one name: a name cannot pick one (the first was taken without a word)
    twin = t.replace('<Alignment name="Gleis 2"', '<Alignment name="Gleis 1"')
    with pytest.raises(AlignmentChoiceError, match="2 alignments are named 'Gleis 1'"):
        read_landxml(twin, "Gleis 1")
    assert read_landxml(twin, "Abstellgleis 3").alignment.name == "Abstellgleis 3"


def test_export_names_the_alignment_of_a_file_holding_several(tmp_path):
    # trolley export --design FILE --design-name NAME (review of 2026-11-26: the error said to
    # choose by name, and export had no option for it)
    from typer.testing import CliRunner

    from survey.cli import app

    rows = ["chainage_m,E_m,N_m,H_m,sigma_E_mm,sigma_N_mm,sigma_H_mm,lateral_dev_mm,vertical_dev_mm,gauge_mm,"
            "cant_mm,twist_mm,distance_m"]
    for d in 1296.0 + np.arange(40) * 0.625:
        e, n = hand_position(d, e0=E0 - 4.5)           # the trolley on Gleis 2
        rows.append(f"{d:.6f},{e:.6f},{n:.6f},100.0,0.5,0.5,0.5,,,1435.0,0.0,,{d:.6f}")
    (tmp_path / "track.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    (tmp_path / "design.xml").write_text(text("several_alignments.xml"), encoding="utf-8")
    run = CliRunner().invoke
    base = ["export", str(tmp_path / "track.csv"), "--design", str(tmp_path / "design.xml")]
    r = run(app, base + ["--csv", str(tmp_path / "a.csv")])
    assert r.exit_code == 2 and "3 alignments" in r.stderr and "--design-name" in r.stderr
    assert not (tmp_path / "a.csv").exists()
    r = run(app, base + ["--csv", str(tmp_path / "b.csv"), "--design-name", "Gleis 2"])
    assert r.exit_code == 0, r.stderr
    import pandas as pd

    b = pd.read_csv(tmp_path / "b.csv")
    assert np.allclose(b["design_E_m"], b["E_m"], atol=1e-5) and np.allclose(b["design_N_m"], b["N_m"], atol=1e-5)
    r = run(app, base + ["--csv", str(tmp_path / "c.csv"), "--design-name", "Gleis 1", "--json"])
    assert r.exit_code == 0
    c = pd.read_csv(tmp_path / "c.csv")
    # Gleis 1 is Gleis 2 moved 4.5 m east; the stations lie on its R 800 m arc, whose centre is
    # (E 400616.5064, N 5599432.1797): the offset from Gleis 1 is R - |P - C| (right positive, the
    # curve turns right), the design point is the foot, and the chainages are Gleis 2's, not Gleis 1's
    by_hand_mm = 1e3 * (800.0 - np.hypot(c["E_m"] - 400616.5064, c["N_m"] - 5599432.1797))
    assert np.allclose(c["lateral_dev_mm"], by_hand_mm, atol=0.05) and (by_hand_mm < -1900).all()
    assert np.allclose(np.hypot(c["design_E_m"] - c["E_m"], c["design_N_m"] - c["N_m"]),
                       np.abs(by_hand_mm) / 1e3, atol=1e-4)
    assert any("not this design's stationing" in n for n in json.loads(r.stdout)["notes"])
    assert json.loads(r.stdout)["passed"] is False and json.loads(r.stdout)["defects"] > 0


def test_cli_lists_the_names_then_imports_by_name(tmp_path):
    from survey.cli import app
    from survey.store import ProjectStore

    runner = CliRunner()
    root = str(tmp_path)
    assert runner.invoke(app, ["project", "new", "l7", "--root", root]).exit_code == 0
    f = str(DATA / "several_alignments.xml")
    res = runner.invoke(app, ["project", "import-alignment", f, "--project", "l7", "--root", root])
    assert res.exit_code == 2 and "Traceback" not in res.stderr
    for name in ("Gleis 1", "Gleis 2", "Abstellgleis 3", "--name"):
        assert name in res.stderr, res.stderr
    res = runner.invoke(app, ["project", "import-alignment", f, "--project", "l7", "--root", root,
                              "--name", "Gleis 2"])
    assert res.exit_code == 0, res.stderr
    assert "alignment 'Gleis 2', 3 elements" in res.stdout
    with ProjectStore.open_project(tmp_path, "l7") as store:
        rec = store.alignment()
        assert rec.name == "Gleis 2" and rec.alignment_name == "Gleis 2"
        assert_at(rec.design(), 1600.0, hand_position(1600.0, e0=E0 - 4.5))  # read again by its name
    res = runner.invoke(app, ["project", "import-alignment", str(DATA / "feature_and_extensions.xml"),
                              "--project", "l7", "--root", root])
    assert res.exit_code == 0, res.stderr
    assert res.stderr.count("note: ") == 6 and "<Feature> in Profile/ProfAlign" in res.stderr


def test_feature_and_extensions_skipped_with_notes_geometry_unchanged():
    d = read_landxml(text("feature_and_extensions.xml"))
    joined = "\n".join(d.notes)
    for fragment in ("<Feature> in CoordGeom ", "<Feature> in CoordGeom/Line", "<Feature> in Profile/ProfAlign",
                     "<Feature> in the alignment", "<Superelevation> in the alignment",
                     "<Trasse> (urn:example:vendor-extension extension) in CoordGeom"):
        assert fragment in joined, joined
    base = read_landxml(text("several_alignments.xml"), "Gleis 1").alignment
    s = np.linspace(1000.0, 1750.0, 301)
    a, b = d.alignment.evaluate(s), base.evaluate(s)
    assert np.array_equal(a.E_m, b.E_m) and np.array_equal(a.H_m, b.H_m) and np.array_equal(a.cant_rad, b.cant_rad)


def test_direction_breaks_of_2e5_rad_do_not_accumulate():
    d = read_landxml(text("direction_breaks.xml"))
    assert d.notes == ()  # below DIRECTION_TOLERANCE_RAD (1e-4 rad)
    hz = d.alignment.horizontal
    np.testing.assert_allclose(hz.join_turn_rad, [2e-5, 2e-5], atol=1e-6)
    assert np.max(hz.join_gap_m) < 1e-4
    brk = (2e-5, 2e-5)
    for s in (1100.0, 1300.0, 1449.0, 1600.0, 1750.0):
        assert_at(d.alignment, s, hand_position(s, brk))
    # the same elements chained from the first start (the import before): the far end misses
    chained = HorizontalAlignment.from_elements(hz.start_E_m, hz.start_N_m, hz.start_heading_rad, hz.elements,
                                                hz.start_chainage_m)
    far = chained.evaluate(1750.0)
    e, n = hand_position(1750.0, brk)
    miss_mm = units.m_to_mm(math.hypot(float(far.E_m) - e, float(far.N_m) - n))
    # 2e-5 rad about the arc start over the 479 m to the end, plus 2e-5 rad over the 300 m straight
    assert 14.0 < miss_mm < 16.5, miss_mm


def test_a_large_direction_break_is_reported_at_its_element():
    d = read_landxml(text("direction_break_large.xml"))
    assert len(d.notes) == 1
    note = d.notes[0]
    assert "<Line> no. 3" in note and "<Curve> no. 2" in note and "3.00e-04 rad" in note, note
    assert_at(d.alignment, 1700.0, hand_position(1700.0, (0.0, 3e-4)))
    # the last straight turned by a further 0.02 rad about its Start: not one alignment
    t = text("direction_break_large.xml")
    block = t[t.rindex("<Line "):]
    start = [float(v) for v in block.split("<Start>")[1].split("<")[0].split()]
    end_text = block.split("<End>")[1].split("<")[0]
    end = [float(v) for v in end_text.split()]
    z = complex(*start) + (complex(*end) - complex(*start)) * complex(math.cos(0.02), math.sin(0.02))
    with pytest.raises(LandXmlError, match=r"<Line> no. 3 .*2\.03e-02 rad.*do not join"):
        read_landxml(t.replace(end_text, f"{z.real:.4f} {z.imag:.4f}"))


def test_zero_length_curve_skipped():
    d = read_landxml(text("zero_length_curve.xml"))
    assert len(d.notes) == 1 and "<Curve> no. 2" in d.notes[0] and "zero length" in d.notes[0]
    assert len(d.alignment.horizontal.elements) == 3
    for s in (1200.0, 1250.0, 1400.0, 1700.0):
        assert_at(d.alignment, s, hand_position(s))


def test_overlapping_vertical_curves():
    d = read_landxml(text("overlapping_vertical_curves.xml"))
    assert len(d.notes) == 1 and "<ParaCurve> no. 2" in d.notes[0] and "0.400 mm" in d.notes[0], d.notes
    # hand: first curve 1200..1400, g 0.01 -> -0.01: H = 103 + 0.01 * 50 - 0.02 * 150^2 / 400
    assert float(d.alignment.evaluate(1350.0).H_m) == pytest.approx(102.375, abs=1e-9)
    # in the 0.4 mm overlap the heights of the two curves agree to 4e-10 m
    h = d.alignment.evaluate(np.array([1399.9996, 1400.0])).H_m
    assert h[1] == pytest.approx(103.0 - 0.01 * 100.0 + 0.0, abs=1e-6)
    with pytest.raises(LandXmlError, match=r"<ParaCurve> no. 2.*overlap by 5\.000 mm \(refused above 1 mm\)"):
        read_landxml(text("overlapping_vertical_curves_5mm.xml"))


def test_wrong_declared_length_reported_geometry_used():
    d = read_landxml(text("wrong_declared_length.xml"))
    assert len(d.notes) == 1 and "length=750.5000" in d.notes[0] and "+500.0 mm" in d.notes[0]
    assert d.alignment.end_chainage_m == pytest.approx(1750.0, abs=1e-4)
    assert_at(d.alignment, 1750.0, hand_position(1750.0))


def test_station_equation_drawing_stationing_and_cant_after_it():
    d = read_landxml(text("station_equation.xml"))
    al = d.alignment
    assert "read as drawing stations" in d.notes[0], d.notes
    assert al.stationing.equations == (StationEquation(1300.0, 2300.0, 1300.0, True),)
    np.testing.assert_allclose(al.station([1000.0, 1299.0, 1300.0, 1600.0, 1750.0]),
                               [1000.0, 1299.0, 2300.0, 2600.0, 2750.0], atol=1e-9)
    # cant stations 2450 / 2470 (drawing) are internal 1450 (arc end) / 1470
    full, half = math.asin(0.080 / 1.5), math.asin(0.040 / 1.5)     # linear in height
    c = al.evaluate(np.array([1240.0, 1300.0, 1449.0, 1460.0, 1480.0])).cant_rad
    np.testing.assert_allclose(c, [half, full, full, half, 0.0], atol=1e-12)
    # PVIs 2500 / 2750 (drawing) are internal 1500 / 1750: H(1600) = 101 + 100 / 250
    h = al.evaluate(np.array([1300.0, 1600.0, 1750.0])).H_m
    np.testing.assert_allclose(h, [103.0 - 100.0 * 2.0 / 300.0, 101.4, 102.0], atol=1e-9)
    assert_at(al, 1600.0, hand_position(1600.0))


def test_cant_station_beyond_the_end_refused_with_its_station():
    with pytest.raises(LandXmlError) as info:
        read_landxml(text("cant_beyond_end.xml"))
    msg = str(info.value)
    for fragment in ("<CantStation> no. 5", 'station="2760.000"', "beyond the alignment end by 10.0000 m",
                     "1000.0000 .. 2750.0000 drawing"):
        assert fragment in msg, msg
    # without the equation the drawing stations of the cant are read as internal: the first one
    # past the end is named
    no_eq = "\n".join(line for line in text("station_equation.xml").splitlines() if "StaEquation" not in line)
    with pytest.raises(LandXmlError, match=r"<CantStation> no. 3 .*2450\.0000 lies beyond the alignment end "
                                           r"by 700\.0000 m"):
        read_landxml(no_eq)


def test_us_survey_foot_and_international_foot():
    us, ft = units.US_SURVEY_FOOT_M, units.INTERNATIONAL_FOOT_M
    assert us == 1200.0 / 3937.0 and ft == 0.3048
    d = read_landxml(text("imperial_us_survey_foot.xml"), rail_spacing_m=None)
    al = d.alignment
    assert "USSurveyFoot" in d.notes[0]
    # stations were written to 0.001 ft: the start is 3280.833 ft
    assert al.start_chainage_m == pytest.approx(3280.833 * us, abs=1e-12)
    shift = al.start_chainage_m - 1000.0
    for s in (1100.0, 1350.0, 1700.0):
        assert_at(al, s + shift, hand_position(s))
    # cant 80 mm written as 3.1496 in over a gauge of 4.7083 ft
    c = float(al.evaluate(1350.0 + shift).cant_rad)
    assert c == pytest.approx(math.asin(3.1496 * 0.0254 / (4.7083 * us)), abs=1e-12)
    assert float(al.evaluate(1350.0 + shift).H_m) == pytest.approx(102.375, abs=2e-4)
    # the same numbers as international feet: every number 2 ppm smaller
    intl = read_landxml(text("imperial_international_foot.xml"), rail_spacing_m=None).alignment
    n_ft = float(text("imperial_us_survey_foot.xml").split("<Start>")[1].split()[0])
    assert intl.horizontal.start_N_m == pytest.approx(n_ft * ft, abs=1e-9)
    assert al.horizontal.start_N_m == pytest.approx(n_ft * us, abs=1e-9)
    assert al.horizontal.start_N_m - intl.horizontal.start_N_m == pytest.approx(n_ft * (us - ft), abs=1e-9)
    assert intl.horizontal.length_m == pytest.approx(al.horizontal.length_m * ft / us, abs=1e-9)


# --------------------------------------------------------------------------------------------
def test_stationing_backward_equation_resolves_by_order():
    # 0..100 internal; at 60 the stationing goes back to 50 (stations 50..60 occur twice)
    st_ = Stationing(0.0, 100.0, [StationEquation(60.0, 50.0, 60.0)])
    np.testing.assert_allclose(st_.station([10.0, 59.0, 60.0, 70.0]), [10.0, 59.0, 50.0, 60.0])
    np.testing.assert_allclose(st_.internal_of([55.0, 58.0, 55.0, 80.0]), [55.0, 58.0, 65.0, 90.0])
    fwd = Stationing(0.0, 100.0, [StationEquation(60.0, 1000.0, 60.0)])
    with pytest.raises(StationNotFound) as info:
        fwd.internal_of([10.0, 500.0])
    assert info.value.index == 1
    dec = Stationing(0.0, 100.0, [StationEquation(40.0, 900.0, None, increasing=False)])
    np.testing.assert_allclose(dec.station([50.0]), [890.0])
    np.testing.assert_allclose(dec.internal_of([20.0, 895.0, 870.0]), [20.0, 45.0, 70.0])
    with pytest.raises(ValueError, match="not inside the alignment"):
        Stationing(0.0, 100.0, [StationEquation(100.0, 5.0)])


@given(st.lists(st.floats(0.0, 1000.0), min_size=1, max_size=20),
       st.lists(st.tuples(st.floats(1.0, 999.0), st.floats(-5000.0, 5000.0)), max_size=4))
@example(points=[2.0], eqs=[(1.0, 0.0)])  # station 1.0 occurs first as the back station at 1.0
@settings(max_examples=80, deadline=None)
def test_stationing_round_trip(points, eqs):
    eqs = sorted({round(i, 3): a for i, a in eqs}.items())
    st_ = Stationing(0.0, 1000.0, [StationEquation(i, a) for i, a in eqs])
    s = np.sort(np.asarray(points))
    wanted = st_.station(s)
    back = st_.internal_of(wanted, tol_m=1e-9)
    # the same drawing stations, in order, each at its earliest place (a station that occurs
    # twice after a backward jump resolves to the first occurrence not behind its predecessor).
    # That place may be an equation itself, reached as its back station, where station() gives
    # the station ahead: there the back station is the one to compare.
    ahead = st_.station(back)
    behind = ahead.copy()
    for k, (internal, _) in enumerate(eqs):
        behind[np.abs(back - internal) <= 1e-9] = st_.back_station(k)
    assert np.all((np.abs(ahead - wanted) <= 1e-6) | (np.abs(behind - wanted) <= 1e-6)), (ahead, behind, wanted)
    assert np.all(np.diff(back) >= -1e-6) and np.all(back <= s + 1e-6)
    if all(a >= st_.back_station(k) for k, (_, a) in enumerate(eqs)):  # forward jumps only
        np.testing.assert_allclose(back, s, atol=1e-6)


def test_track_csv_chainage_is_the_drawing_station_distance_kept():
    from survey.trackio import TRACK_COLUMNS, track_frame

    n = 8
    s = 1296.0 + np.arange(n) * 1.0
    stations = type("S", (), dict(chainage_m=s, **{c: np.zeros(n) for c in (
        "E_m", "N_m", "H_m", "sigma_E_m", "sigma_N_m", "sigma_H_m", "lateral_dev_m", "vertical_dev_m", "gauge_m",
        "cant_m", "twist_m")}, cov_EN_m2=None, sigma_cant_m=None))()
    result = type("R", (), dict(stations=stations))()
    al = read_landxml(text("station_equation.xml")).alignment
    frame = track_frame(result, al.stationing)
    assert list(frame.columns) == TRACK_COLUMNS and TRACK_COLUMNS[12] == "distance_m"
    np.testing.assert_allclose(frame["chainage_m"], [1296, 1297, 1298, 1299, 2300, 2301, 2302, 2303])
    np.testing.assert_allclose(frame["distance_m"], s)
    plain = track_frame(result)
    np.testing.assert_allclose(plain["chainage_m"], s)


@given(st.lists(st.sampled_from(["line", "arc", "clothoid"]), min_size=1, max_size=6),
       st.floats(0.0, 2 * math.pi), st.integers(0, 2**31 - 1))
@settings(max_examples=40, deadline=None)
def test_anchored_at_the_chained_starts_is_the_chained_geometry(kinds, heading, seed):
    """Two constructions: chained from one start, and each element anchored where the chain puts it."""
    from trolley.alignment import Arc, Clothoid, Line

    rng = np.random.default_rng(seed)
    k = 0.0
    els = []
    for kind in kinds:
        length = float(rng.uniform(5.0, 300.0))
        if kind == "line":
            els.append(Line(length))
            k = 0.0
        elif kind == "arc":
            k = float(rng.choice([-1, 1]) / rng.uniform(300.0, 5000.0))
            els.append(Arc(length, k))
        else:
            k1 = float(rng.choice([-1, 1]) / rng.uniform(300.0, 5000.0))
            els.append(Clothoid(length, k, k1))
            k = k1
    chained = HorizontalAlignment.from_elements(400000.0, 5600000.0, heading, els, 1000.0)
    n = len(els)
    anchored = HorizontalAlignment.from_anchored_elements(chained.element_E_m[:n], chained.element_N_m[:n],
                                                          chained.element_heading_rad[:n], els, 1000.0)
    assert np.max(anchored.join_gap_m, initial=0.0) < 1e-9 and np.max(np.abs(anchored.join_turn_rad), initial=0.0) < 1e-12
    s = np.linspace(990.0, chained.end_chainage_m + 10.0, 200)
    a, b = chained.evaluate(s), anchored.evaluate(s)
    assert np.max(np.hypot(a.E_m - b.E_m, a.N_m - b.N_m)) < 1e-8
    assert np.max(np.abs(np.angle(np.exp(1j * (a.heading_rad - b.heading_rad))))) < 1e-12


def test_projection_onto_elements_with_direction_breaks():
    al = read_landxml(text("direction_break_large.xml")).alignment
    s = np.array([1010.0, 1249.0, 1300.0, 1449.0, 1451.0, 1600.0, 1749.0])
    p = al.evaluate(s)
    # 1.2 m to the right of each point (heading + 90 deg)
    e = p.E_m + 1.2 * np.cos(p.heading_rad)
    n = p.N_m - 1.2 * np.sin(p.heading_rad)
    proj = al.project(e, n)
    np.testing.assert_allclose(proj.chainage_m, s, atol=1e-6)
    np.testing.assert_allclose(proj.lateral_m, 1.2, atol=1e-6)


def test_written_file_reads_back_with_its_joins_and_equations():
    from trolley.landxml import landxml_text

    al = read_landxml(text("station_equation.xml")).alignment
    back = read_landxml(landxml_text(al))
    assert back.alignment.stationing.equations == al.stationing.equations
    s = np.linspace(1000.0, 1750.0, 101)
    a, b = al.evaluate(s), back.alignment.evaluate(s)
    assert np.max(np.hypot(a.E_m - b.E_m, a.N_m - b.N_m)) < 1e-6
    np.testing.assert_allclose(b.cant_rad, a.cant_rad, atol=1e-9)
    np.testing.assert_allclose(b.H_m, a.H_m, atol=1e-9)
    brk = read_landxml(text("direction_break_large.xml")).alignment
    again = read_landxml(landxml_text(brk))
    np.testing.assert_allclose(again.alignment.horizontal.join_turn_rad, brk.horizontal.join_turn_rad, atol=1e-9)
    assert len(again.notes) == 1 and "<Line> no. 3" in again.notes[0]


def test_session_toml_names_the_alignment_of_a_file_holding_several(tmp_path):
    from dataclasses import replace

    from survey.sessionio import read_design, read_session_meta, session_toml_text
    from survey.store import ProjectSettings

    meta = replace(ProjectSettings().session_meta("design.xml"), design_alignment_name="Gleis 2")
    (tmp_path / "session.toml").write_text(session_toml_text(meta), encoding="utf-8")
    (tmp_path / "design.xml").write_text(text("several_alignments.xml"), encoding="utf-8")
    back = read_session_meta(tmp_path)
    assert back.design_alignment_name == "Gleis 2"
    assert_at(read_design(tmp_path, back), 1600.0, hand_position(1600.0, e0=E0 - 4.5))


def test_export_reads_track_csv_along_distance_and_says_so(tmp_path):
    from survey.track_reader import add_design, read_track_csv

    s = 1296.0 + np.arange(8) * 1.0
    drawing = read_landxml(text("station_equation.xml")).alignment.station(s)
    rows = ["chainage_m,E_m,N_m,H_m,sigma_E_mm,sigma_N_mm,sigma_H_mm,lateral_dev_mm,vertical_dev_mm,gauge_mm,"
            "cant_mm,twist_mm,distance_m"]
    for c, d in zip(drawing, s):
        e, n = hand_position(d)
        rows.append(f"{c:.6f},{e:.6f},{n:.6f},100.0,0.5,0.5,0.5,,,,,,{d:.6f}")
    (tmp_path / "track.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    (tmp_path / "design.xml").write_text(text("station_equation.xml"), encoding="utf-8")
    track, _ = read_track_csv(tmp_path / "track.csv")  # chainage_m jumps 1299 -> 2300: read along distance_m
    np.testing.assert_allclose(track.chainage_m, s)
    notes: list[str] = []
    track, stationing = add_design(track, tmp_path / "design.xml", 1.5, None, notes)
    np.testing.assert_allclose(stationing.station(s), drawing)
    np.testing.assert_allclose(track.design_E_m, track.E_m, atol=POS_TOL_M)
    assert any("station equations" in n and "distance_m" in n for n in notes), notes
    assert any("read as drawing stations" in n for n in notes), notes


def test_a_drawing_stationed_profile_running_past_the_end_is_read_as_drawing_stations():
    # (bug hunt 2026-11-26) the profile in drawing stations, 150 m longer than the track, without
    # cant: read as internal stations its last PVIs lie 750 and 1150 m beyond the end, and the
    # heights were 1.27 m off. By hand at drawing 2500 (internal 1500), the PVI of a 200 m parabola:
    # its height plus A L / 8, A the change of grade there (-0.02/3 to +0.004 with the last PVI at
    # the end; the same height with the profile run on along its grade), 101.2667
    import re

    base = re.sub(r"<Cant .*?</Cant>", "", text("station_equation.xml"), flags=re.S)
    prof = ('<PVI>1000.000 100.0000</PVI>\n<ParaCurve length="100.0000">1200.000 103.0000</ParaCurve>\n'
            '<ParaCurve length="200.0000">2500.000 101.0000</ParaCurve>\n<PVI>LAST</PVI>')
    base, n = re.subn(r"<PVI>1000.000.*?<PVI>2750.000 102.0000</PVI>", prof, base, flags=re.S)
    assert n == 1
    for last in ("2750.000 102.0000", "2900.000 102.6000"):
        d = read_landxml(base.replace("LAST", last))
        assert "read as drawing stations" in d.notes[-1]
        assert d.alignment.station(1500.0) == pytest.approx(2500.0)
        assert d.alignment.evaluate(np.array([1500.0])).H_m[0] == pytest.approx(101.0 + (0.004 + 0.02 / 3) * 25,
                                                                             abs=1e-4)


def test_a_station_out_of_order_is_named_as_the_file_gives_it():
    # (bug hunt 2026-11-26) "PVI 3: chainage np.float64(1500.0) does not increase": counted from 0,
    # numpy's repr, and the internal station where the file says 2500
    import re

    t = text("station_equation.xml")
    twice = t.replace("<PVI>2750.000 102.0000</PVI>", "<PVI>2500.000 101.0000</PVI><PVI>2750.000 102.0000</PVI>")
    with pytest.raises(LandXmlError, match=r"<PVI> no\. 4: station 2500\.0000 m does not come after the one before it "
                                           r"\(2500\.0000 m\)"):
        read_landxml(twice)
    cs = re.findall(r"<CantStation[^>]*/>", t)
    with pytest.raises(LandXmlError, match=r'<CantStation> no\. 4 \(station="2450\.000"\): station 2450\.0000 m does not'):
        read_landxml(t.replace(cs[2], cs[2] + cs[2]))


def test_an_arc_the_wrong_way_round_is_refused_by_the_alignments_own_length():
    # (bug hunt 2026-11-26) one Curve with rot reversed and no length attribute became a 4826 m arc
    # with only a note against Alignment length="200"; a rounded total is still only noted
    xml = """<?xml version="1.0" encoding="UTF-8"?>
<LandXML xmlns="http://www.landxml.org/schema/LandXML-1.2" version="1.2">
  <Units><Metric linearUnit="meter"/></Units>
  <Alignments><Alignment name="A" length="LENGTH" staStart="1250.0">
    <CoordGeom>
      <Curve rot="ROT" crvType="arc" staStart="1250.000">
        <Start>5600125.0000 400216.5064</Start><Center>5599432.1797 400616.5064</Center>
        <End>5600202.4235 400400.3479</End>
      </Curve>
    </CoordGeom>
  </Alignment></Alignments>
</LandXML>
"""
    with pytest.raises(LandXmlError, match=r"length=200\.0000 but its elements add up to 4826\.5"):
        read_landxml(xml.replace("LENGTH", "200.0000").replace("ROT", "ccw"))
    d = read_landxml(xml.replace("LENGTH", "200.05").replace("ROT", "cw"))
    assert abs(d.alignment.horizontal.length_m - 200.0) < 1e-3
    assert any("length=200.05 but its elements add up to" in n for n in d.notes)


def test_one_element_off_its_stationing_is_noted_once():
    # (bug hunt 2026-11-26) the element after it, which agrees, was noted as "-0.0 mm" off
    t = text("station_equation.xml").replace('<Curve staStart="1250.000"', '<Curve staStart="1251.000"')
    notes = [n for n in read_landxml(t).notes if "staStart is" in n]
    assert len(notes) == 1 and 'staStart="1251.000"): staStart is +1000.0 mm' in notes[0]


def test_a_profile_shorter_than_the_alignment_is_noted():
    # (bug hunt 2026-11-26) its heights were extended along the end grade without a word
    t = text("several_alignments.xml")
    short = t.replace("<PVI>1750.000 102.0000</PVI>", "<PVI>1700.000 101.8000</PVI>")
    d = read_landxml(short, "Gleis 1")
    assert any("the profile covers 1000.0000 .. 1700.0000, the alignment 1000.0000 .. 1750.0000" in n
               for n in d.notes)
    assert not any("the profile covers" in n for n in read_landxml(t, "Gleis 1").notes)
