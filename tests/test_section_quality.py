"""Per-section standard deviation (trolley.sectionquality, EN 13848-6 style): hand-computed and
against numpy on each section."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st

from trolley.sectionquality import section_quality


def test_hand_computed_sections():
    # stations every 50 m from 0 to 550: sections 0-200, 200-400, 400-600 hold 4 stations each
    s = np.arange(0.0, 600.0, 50.0)
    x = np.array([1.0, 3.0, 1.0, 3.0,          # mean 2, deviations +-1: SD 1
                  0.0, 0.0, 4.0, 4.0,          # mean 2, deviations +-2: SD 2
                  5.0, np.nan, np.nan, 7.0])   # 2 of 4 valid (= min_fraction 0.5): mean 6, SD 1
    q = section_quality(s, x)
    assert q.start_m.tolist() == [0.0, 200.0, 400.0] and q.end_m.tolist() == [200.0, 400.0, 600.0]
    assert q.count.tolist() == [4, 4, 2] and q.expected.tolist() == [4, 4, 4]
    assert q.mean.tolist() == [2.0, 2.0, 6.0]
    assert q.std.tolist() == [1.0, 2.0, 1.0]
    # one more NaN: too few valid stations, no SD
    x[8] = np.nan
    assert np.isnan(section_quality(s, x).std[2])


def test_sections_aligned_on_multiples_of_the_length():
    s = np.arange(150.0, 450.0, 10.0)          # 150 .. 440: sections 0-200 (5), 200-400 (20), 400-600 (5)
    q = section_quality(s, np.zeros(s.size), min_fraction=0.0)
    assert q.start_m.tolist() == [0.0, 200.0, 400.0]
    assert q.count.tolist() == [5, 20, 5]


def test_bad_arguments():
    with pytest.raises(ValueError, match="section length"):
        section_quality(np.arange(3.0), np.zeros(3), length_m=0.0)
    with pytest.raises(ValueError, match="one length"):
        section_quality(np.arange(3.0), np.zeros(4))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-50, 50), min_size=3, max_size=300), st.floats(5.0, 120.0), st.floats(-500, 500))
@example(values=[0.0, 0.0, 0.0], length=5.0, s0=-5e-324)  # s / length rounds up to the boundary 0
def test_equals_numpy_std_of_each_section(values, length, s0):
    x = np.array(values)
    s = s0 + 1.7 * np.arange(x.size)
    q = section_quality(s, x, length_m=length, min_fraction=0.0)
    for a, b, sd, n in zip(q.start_m, q.end_m, q.std, q.count):
        sel = (s >= a) & (s < b)
        assert n == sel.sum()
        if n:
            assert sd == pytest.approx(np.std(x[sel]), abs=1e-9)


def test_a_section_the_survey_only_touches_gets_no_sd_with_the_grid_step():
    s = np.arange(0.0, 401.0, 10.0)             # 0 .. 400: the last section holds one station
    x = np.sin(s)
    assert np.isfinite(section_quality(s, x).std[-1])            # one station of one expected
    q = section_quality(s, x, step_m=10.0)
    assert q.expected.tolist() == [20, 20, 20] and np.isnan(q.std[-1]) and np.isfinite(q.std[:2]).all()
