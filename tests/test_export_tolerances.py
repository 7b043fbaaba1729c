"""Tolerance sets: parsing, built-in files, defects as runs with peak and limit."""
from __future__ import annotations

import numpy as np
import pytest

from survey.tolerance_files import builtin_tolerance_names, load_tolerances
from trolley.tolerances import ToleranceError, find_defects, parse_tolerances
from trolley.trackgeometry import GeometryConfig, column_names

GOOD = """
format = "trolley-tolerances/1"
name = "t"
[geometry]
twist_base_m = 6.25
[limits.gauge_dev]
max_abs_mm = 1.0
source = "test"
[limits.twist_rate]
max_abs_mm_per_m = 2.0
example = true
[limits.gauge]
min_mm = 1430
max_mm = 1440
source = "test"
"""


def test_parse_converts_to_si_and_keeps_sources():
    t = parse_tolerances(GOOD, "good.toml")
    assert t.twist_base_m == 6.25 and t.versine_chord_m is None
    by = {lim.parameter: lim for lim in t.limits}
    assert by["gauge_dev"].column == "gauge_dev_m"
    assert (by["gauge_dev"].lower, by["gauge_dev"].upper) == pytest.approx((-0.001, 0.001))
    assert by["twist_rate"].column == "twist_rate_m_per_m" and by["twist_rate"].upper == pytest.approx(0.002)
    assert by["twist_rate"].example and by["gauge_dev"].source == "test"
    assert (by["gauge"].lower, by["gauge"].upper) == pytest.approx((1.430, 1.440))


@pytest.mark.parametrize("bad, msg", [
    (GOOD.replace('source = "test"\n[limits.twist_rate]', '[limits.twist_rate]'), "source or example"),
    (GOOD.replace("max_abs_mm = 1.0", "max_abs_inch = 1.0"), "needs min_<unit>"),
    (GOOD.replace('format = "trolley-tolerances/1"', 'format = "x"'), "format"),
    (GOOD.replace("max_abs_mm = 1.0", "max_abs_mm = 1.0\nmin_mm = 0.0"), "max_abs together"),
    (GOOD.replace("twist_base_m = 6.25", "twist_base = 6.25"), "unknown key"),
    (GOOD + "\n[limits.x\n", "not valid TOML"),
])
def test_bad_tolerance_files_name_file_and_key(bad, msg):
    with pytest.raises(ToleranceError, match=msg) as e:
        parse_tolerances(bad, "bad.toml")
    assert "bad.toml" in str(e.value)


def test_builtin_sets_load_and_cover_known_columns_with_sources():
    names = builtin_tolerance_names()
    assert {"hsr_ballastless_static", "en13848_5_alert"} <= set(names)
    cols = set(column_names(GeometryConfig()))
    for name in names:
        t = load_tolerances(name)
        assert t.limits
        for lim in t.limits:
            assert lim.column in cols, (name, lim.column)
            assert lim.source or lim.example
    hsr = {lim.parameter: lim for lim in load_tolerances("hsr_ballastless_static").limits}
    assert hsr["chord300_150_lat"].upper == pytest.approx(0.010)
    assert hsr["gauge_rate"].upper == pytest.approx(1 / 1500, rel=1e-3)


def test_user_file_and_unknown_name(tmp_path):
    p = tmp_path / "mine.toml"
    p.write_text(GOOD, encoding="utf-8")
    assert load_tolerances(str(p)).name == "t"
    # saved by Notepad with a byte-order mark (bug hunt 2026-11-26: "Invalid statement at line 1")
    bom = tmp_path / "bom.toml"
    bom.write_text(GOOD, encoding="utf-8-sig")
    assert bom.read_bytes()[:3] == b"\xef\xbb\xbf"
    assert load_tolerances(str(bom)).limits == load_tolerances(str(p)).limits
    with pytest.raises(ToleranceError, match="neither a built-in"):
        load_tolerances("no_such_set")


def test_defects_are_runs_with_peak_and_violated_limit():
    t = parse_tolerances(GOOD, "good.toml")
    s = np.arange(20) * 0.5
    gauge_dev = np.zeros(20)
    gauge_dev[3:6] = [0.0012, 0.0019, 0.0011]        # one run above +1 mm, peak 1.9 mm at s = 2.0
    gauge_dev[10] = -0.0015                          # one station below -1 mm
    gauge_dev[15] = np.nan                           # missing: never a defect
    cols = {"gauge_dev_m": gauge_dev, "twist_rate_m_per_m": np.zeros(20), "gauge_m": 1.435 + gauge_dev}
    d = find_defects(s, cols, t)
    assert [(x.parameter, x.start_chainage_m, x.end_chainage_m, x.stations) for x in d] == [
        ("gauge_dev", 1.5, 2.5, 3), ("gauge_dev", 5.0, 5.0, 1)]
    assert d[0].peak == pytest.approx(0.0019) and d[0].limit == pytest.approx(0.001)
    assert d[1].peak == pytest.approx(-0.0015) and d[1].limit == pytest.approx(-0.001)
    with pytest.raises(ToleranceError, match=r"\[limits.twist_rate\]: no such parameter \(known: gauge_dev\)"):
        find_defects(s, {"gauge_dev_m": gauge_dev}, t)
    # a key given in the other unit is named with the unit it takes
    wrong = parse_tolerances('format = "trolley-tolerances/1"\nname = "w"\n[limits.gauge_dev]\n'
                             'max_abs_mm_per_m = 1.0\nexample = true\n', "w.toml")
    with pytest.raises(ToleranceError, match=r"w.toml: \[limits.gauge_dev\]: gauge_dev is in mm, not mm/m: use "
                                             r"min_mm / max_mm / max_abs_mm"):
        find_defects(s, cols, wrong)


def _defects_by_loop(s, v, lo, hi):
    """Reference: walk the stations one by one."""
    out, run = [], None
    for i, x in enumerate(v):
        bad = x == x and (x < lo or x > hi)
        if bad:
            exc = x - hi if x > hi else lo - x
            if run is None:
                run = [i, i, i, exc]
            else:
                run[1] = i
                if exc > run[3]:
                    run[2], run[3] = i, exc
        elif run is not None:
            out.append((s[run[0]], s[run[1]], v[run[2]], run[1] - run[0] + 1))
            run = None
    if run is not None:
        out.append((s[run[0]], s[run[1]], v[run[2]], run[1] - run[0] + 1))
    return out


from hypothesis import given, settings, strategies as st  # noqa: E402


@settings(max_examples=50, deadline=None)
@given(vals=st.lists(st.one_of(st.floats(-3e-3, 3e-3), st.just(float("nan"))), min_size=1, max_size=60))
def test_find_defects_matches_station_loop(vals):
    t = parse_tolerances(GOOD, "good.toml")
    v = np.array(vals)
    s = np.arange(v.size) * 0.625
    cols = {"gauge_dev_m": v, "twist_rate_m_per_m": np.zeros(v.size), "gauge_m": np.full(v.size, 1.435)}
    got = [(d.start_chainage_m, d.end_chainage_m, d.peak, d.stations) for d in find_defects(s, cols, t)]
    assert got == _defects_by_loop(s, v, -0.001, 0.001)
