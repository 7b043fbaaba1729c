"""Projection of points onto the design alignment: round trips and a brute-force reference."""
from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings, strategies as st
from scipy.optimize import minimize_scalar

from trolley.alignment import (Alignment, Arc, CantProfile, Clothoid, HorizontalAlignment, Line,
                               VerticalProfile)


def _alignment() -> Alignment:
    k = 1.0 / 600.0
    hz = HorizontalAlignment.from_elements(
        500000.0, 3100000.0, 0.3,
        [Line(100.0), Clothoid(60.0, 0.0, k), Arc(150.0, k), Clothoid(60.0, k, 0.0), Line(80.0),
         Clothoid(50.0, 0.0, -1 / 400), Arc(90.0, -1 / 400), Clothoid(70.0, -1 / 400, -1 / 1500),
         Arc(40.0, -1 / 1500)],
        start_chainage_m=250.0)
    s0, s1 = hz.start_chainage_m, hz.end_chainage_m
    prof = VerticalProfile.from_pvis([s0, 500.0, s1], [40.0, 44.0, 41.0], [0.0, 200.0, 0.0])
    cant = CantProfile.from_stations([350.0, 410.0], [0.0, 0.1])
    return Alignment(hz, prof, cant)


AL = _alignment()


def _offset(al, s, d, dz=0.0):
    r = al.evaluate(s)
    # right normal of bearing h: (E, N) = (cos h, -sin h)
    return (r.E_m + d * np.cos(r.heading_rad), r.N_m - d * np.sin(r.heading_rad), r.H_m + dz)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 1.0), st.floats(-25.0, 25.0), st.floats(-2.0, 2.0)),
                min_size=1, max_size=40))
def test_round_trip_evaluate_offset_project(pts):
    f, d, dz = (np.array(x) for x in zip(*pts))
    s = AL.start_chainage_m + f * (AL.end_chainage_m - AL.start_chainage_m)
    E, N, H = _offset(AL, s, d, dz)
    p = AL.project(E, N, H)
    assert np.max(np.abs(p.chainage_m - s)) < 1e-6
    assert np.max(np.abs(p.lateral_m - d)) < 1e-6
    assert np.max(np.abs(p.vertical_m - dz)) < 1e-6
    assert np.all(p.inside)


def test_round_trip_is_submicrometre_on_many_points():
    rng = np.random.default_rng(7)
    s = rng.uniform(AL.start_chainage_m, AL.end_chainage_m, 20000)
    s[:12] = AL.horizontal.element_chainage_m[[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9]]  # the joins
    d = rng.uniform(-10.0, 10.0, s.size)
    E, N, H = _offset(AL, s, d)
    p = AL.project(E, N, H)
    assert np.max(np.abs(p.chainage_m - s)) < 1e-7
    assert np.max(np.abs(p.lateral_m - d)) < 1e-7
    assert p.chainage_m.shape == s.shape


def test_sign_of_lateral_offset_hand_case():
    # straight heading north from the origin: a point to the east is to the right
    al = Alignment(HorizontalAlignment.from_elements(0.0, 0.0, 0.0, [Line(100.0)]))
    p = al.project(np.array([3.0, -2.0]), np.array([40.0, 70.0]))
    np.testing.assert_allclose(p.chainage_m, [40.0, 70.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(p.lateral_m, [3.0, -2.0], rtol=0, atol=1e-12)
    assert np.all(np.isnan(p.vertical_m))  # no heights given


def test_beyond_the_ends_continues_on_tangents_and_flags_outside():
    hz = AL.horizontal
    s = np.array([hz.start_chainage_m - 30.0, hz.end_chainage_m + 45.0])
    E, N, _ = _offset(AL, s, np.array([2.0, -3.0]))
    p = AL.project(E, N)
    np.testing.assert_allclose(p.chainage_m, s, rtol=0, atol=1e-8)
    np.testing.assert_allclose(p.lateral_m, [2.0, -3.0], rtol=0, atol=1e-8)
    assert not np.any(p.inside)


def test_agrees_with_brute_force_minimum_distance():
    """Independent method: bounded scalar minimisation of the distance over each element."""
    rng = np.random.default_rng(3)
    hz = AL.horizontal
    s_true = rng.uniform(hz.start_chainage_m + 1, hz.end_chainage_m - 1, 40)
    E, N, _ = _offset(AL, s_true, rng.uniform(-40, 40, s_true.size))
    p = AL.project(E, N)
    for e, n, s_got, d_got in zip(E, N, p.chainage_m, p.lateral_m):
        best = (np.inf, None)
        for a, b in zip(hz.element_chainage_m[:-1], hz.element_chainage_m[1:]):
            def dist2(s):
                r = hz.evaluate(np.array([s]))
                return (r.E_m[0] - e) ** 2 + (r.N_m[0] - n) ** 2
            res = minimize_scalar(dist2, bounds=(a, b), method="bounded",
                                  options={"xatol": 1e-9})
            if res.fun < best[0]:
                best = (res.fun, res.x)
        assert abs(math.sqrt(best[0]) - abs(d_got)) < 1e-6
        assert abs(best[1] - s_got) < 1e-3  # xatol of the bounded search on a flat minimum


def test_shape_is_kept():
    s = np.linspace(300.0, 700.0, 12).reshape(3, 4)
    E, N, H = _offset(AL, s, 1.5, 0.25)
    p = AL.project(E, N, H)
    assert p.chainage_m.shape == (3, 4) and p.inside.shape == (3, 4)
    np.testing.assert_allclose(p.vertical_m, 0.25, rtol=0, atol=1e-9)


@st.composite
def chains(draw):
    """Random element chains, including S-curves and curve-to-curve clothoids.

    Radii >= 800 m keep the total turn below pi, so the nearest point is never on another lap.
    """
    n = draw(st.integers(1, 6))
    k = draw(st.sampled_from([0.0, 1 / 800, -1 / 900]))
    els = []
    for _ in range(n):
        L = draw(st.floats(10.0, 300.0))
        kind = draw(st.sampled_from(["line", "arc", "clothoid"]))
        if kind == "line":
            els.append(Line(L))
            k = 0.0
        elif kind == "arc":
            k = k if k != 0.0 else draw(st.sampled_from([1.0, -1.0])) / draw(st.floats(800, 20000))
            els.append(Arc(L, k))
        else:
            k_new = draw(st.sampled_from([1.0, -1.0])) / draw(st.floats(800.0, 20000.0))
            els.append(Clothoid(L, k, k_new))
            k = k_new
    return HorizontalAlignment.from_elements(draw(st.floats(3e5, 7e5)), draw(st.floats(1e6, 8e6)),
                                             draw(st.floats(0, 2 * math.pi)), els,
                                             draw(st.floats(-500.0, 9000.0)))


@settings(max_examples=40, deadline=None)
@given(chains(), st.lists(st.tuples(st.floats(0.0, 1.0), st.floats(-8.0, 8.0)), min_size=1,
                          max_size=30))
def test_round_trip_on_random_chains(hz, pts):
    al = Alignment(hz)
    f, d = (np.array(x) for x in zip(*pts))
    s = hz.start_chainage_m + f * hz.length_m
    E, N, _ = _offset(al, s, d)
    p = al.project(E, N)
    assert np.max(np.abs(p.chainage_m - s)) < 1e-6
    assert np.max(np.abs(p.lateral_m - d)) < 1e-6
