"""Design geometry evaluation: hand cases, an independent quadrature, continuity, derivatives."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.integrate import quad
from scipy.special import fresnel

from trolley.alignment import (Alignment, Arc, CantProfile, Clothoid, HorizontalAlignment, Line,
                               VerticalProfile)


def _quad_position(h0, k0, c, u):
    """Independent reference: numerical quadrature of (sin, cos) of the heading."""
    def heading(v):
        return h0 + k0 * v + 0.5 * c * v * v
    e = quad(lambda v: math.sin(heading(v)), 0.0, u, epsabs=1e-12, epsrel=1e-13, limit=200)[0]
    n = quad(lambda v: math.cos(heading(v)), 0.0, u, epsabs=1e-12, epsrel=1e-13, limit=200)[0]
    return e, n


def demo_like() -> Alignment:
    k = 1.0 / 3000.0
    hz = HorizontalAlignment.from_elements(
        500000.0, 3100000.0, 1.0,
        [Line(200.0), Clothoid(150.0, 0.0, k), Arc(500.0, k), Clothoid(150.0, k, 0.0), Line(300.0)],
        start_chainage_m=1000.0)
    # a parabola at 1400 and a circle of R_v = 20 km at 1900
    prof = VerticalProfile.from_pvis([1000.0, 1400.0, 1900.0, 2300.0], [50.0, 53.2, 50.7, 51.9],
                                     [0.0, 260.0, 0.0, 0.0], [0.0, 0.0, 20000.0, 0.0])
    cant = CantProfile.from_stations([1200.0, 1350.0, 1850.0, 2000.0], [0.0, 0.08, 0.08, 0.0])
    return Alignment(hz, prof, cant, name="T")


def test_straight_line_hand_values():
    h = math.radians(30.0)
    al = Alignment(HorizontalAlignment.from_elements(10.0, 20.0, h, [Line(100.0)], 5.0))
    r = al.evaluate(np.array([5.0, 55.0, 105.0]))
    np.testing.assert_allclose(r.E_m, 10.0 + np.array([0.0, 25.0, 50.0]), rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.N_m, 20.0 + np.array([0.0, 50.0, 100.0]) * math.cos(h), rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.heading_rad, h, rtol=0, atol=1e-15)
    for arr in (r.rho_h_1_m, r.H_m, r.slope_rad, r.cant_rad, r.rho_v_1_m, r.rho_tw_1_m):
        assert np.all(arr == 0.0)
    assert al.start_chainage_m == 5.0 and al.end_chainage_m == 105.0


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_quarter_circle_endpoint(sign):
    R = 250.0
    hz = HorizontalAlignment.from_elements(0.0, 0.0, 0.0, [Arc(math.pi * R / 2, sign / R)])
    r = hz.evaluate(np.array([math.pi * R / 2, math.pi * R / 4]))
    # heading north, turning right (sign +) ends at (E, N) = (R, R) heading east
    np.testing.assert_allclose(r.E_m, sign * R * np.array([1.0, 1 - math.sqrt(0.5)]), rtol=0, atol=1e-10)
    np.testing.assert_allclose(r.N_m, R * np.array([1.0, math.sqrt(0.5)]), rtol=0, atol=1e-10)
    np.testing.assert_allclose(r.heading_rad[0], (sign * math.pi / 2) % (2 * math.pi), rtol=0, atol=1e-14)
    np.testing.assert_allclose(r.rho_h_1_m, sign / R, rtol=1e-14)


def test_clothoid_endpoint_fresnel_closed_form_and_check_values():
    # protocols.md 3.5: R = 600 m, L = 60 m: x = 59.985, y = 0.9998, tau = 0.05 rad
    R, L = 600.0, 60.0
    A = math.sqrt(R * L)
    hz = HorizontalAlignment.from_elements(0.0, 0.0, 0.0, [Clothoid(L, 0.0, 1.0 / R)])
    r = hz.evaluate(np.array([L]))
    S, C = fresnel(L / (A * math.sqrt(math.pi)))
    x, y = A * math.sqrt(math.pi) * C, A * math.sqrt(math.pi) * S
    assert abs(r.N_m[0] - x) < 1e-12 and abs(r.E_m[0] - y) < 1e-12
    # the textbook series x = L - L^5/(40 A^4), y = L^3/(6 A^2) - L^7/(336 A^6): independent
    assert abs(x - (L - L**5 / (40 * A**4) + L**9 / (3456 * A**8))) < 1e-9
    assert abs(y - (L**3 / (6 * A**2) - L**7 / (336 * A**6) + L**11 / (42240 * A**10))) < 1e-9
    assert abs(r.N_m[0] - 59.985) < 5e-4 and abs(r.E_m[0] - 0.9998) < 5e-5
    assert abs(r.heading_rad[0] - L / (2 * R)) < 1e-15


@pytest.mark.parametrize("k0,k1", [(0.0, 1 / 600), (1 / 600, 0.0), (-1 / 400, -1 / 900),
                                   (1 / 500, -1 / 700), (1 / 300, 1 / 300 + 1e-12),
                                   (-2e-3, -2e-3 - 1e-17)])
def test_clothoid_positions_match_quadrature(k0, k1):
    L, h0 = 180.0, 2.0
    hz = HorizontalAlignment.from_elements(0.0, 0.0, h0, [Clothoid(L, k0, k1)])
    u = np.array([0.0, 1e-3, 37.0, 90.0, 179.0, L])
    r = hz.evaluate(u)
    for ui, e, n in zip(u, r.E_m, r.N_m):
        e_ref, n_ref = _quad_position(h0, k0, (k1 - k0) / L, ui)
        assert abs(e - e_ref) < 1e-9 and abs(n - n_ref) < 1e-9
    np.testing.assert_allclose(r.rho_h_1_m, k0 + (k1 - k0) / L * u, rtol=0, atol=1e-15)
    np.testing.assert_allclose(r.drho_h_ds_1_m2, (k1 - k0) / L, rtol=1e-12, atol=1e-30)


def test_continuity_at_element_joins():
    al = demo_like()
    joins = al.horizontal.element_chainage_m[1:-1]
    eps = 1e-7
    a, b = al.evaluate(joins - eps), al.evaluate(joins + eps)
    assert np.max(np.hypot(a.E_m - b.E_m, a.N_m - b.N_m)) < 3e-7
    assert np.max(np.abs(a.heading_rad - b.heading_rad)) < 1e-10
    # curvature is continuous too (a designed transition), its derivative jumps
    assert np.max(np.abs(a.rho_h_1_m - b.rho_h_1_m)) < 1e-12


def test_parabolic_vertical_curve_hand_values():
    g1, g2, L = 0.008, -0.005, 260.0
    prof = VerticalProfile.from_pvis([0.0, 400.0, 900.0], [50.0, 53.2, 50.7], [0.0, L, 0.0])
    al = Alignment(HorizontalAlignment.from_elements(0, 0, 0, [Line(900.0)]), prof)
    s = np.array([400.0 - L / 2, 400.0, 400.0 + L / 2, 100.0, 800.0])
    r = al.evaluate(s)
    expected = [53.2 - g1 * L / 2, 53.2 + (g2 - g1) * L / 8, 53.2 + g2 * L / 2,
                50.0 + 100 * g1, 53.2 + g2 * 400]
    np.testing.assert_allclose(r.H_m, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.tan(r.slope_rad), [g1, (g1 + g2) / 2, g2, g1, g2], rtol=0, atol=1e-15)
    # vertical radius L / |dg| = 20 000 m on the curve (crest: negative curvature)
    assert abs(r.rho_v_1_m[1] * (1 + ((g1 + g2) / 2) ** 2) - (g2 - g1) / L) < 1e-15
    assert r.rho_v_1_m[3] == 0.0 and r.rho_v_1_m[4] == 0.0


def test_circular_vertical_curve_hand_values():
    # symmetric crest +-1.5 % with R = 10 km: the circle passes R (sec(a) - 1) below the PVI,
    # with a = arctan(0.015), and starts/ends T cos(a) = R sin(a) either side of it
    R, g = 10000.0, 0.015
    a = math.atan(g)
    prof = VerticalProfile.from_pvis([0.0, 500.0, 1000.0], [0.0, 7.5, 0.0], [0.0, 0.0, 0.0],
                                     [0.0, R, 0.0])
    assert abs(prof.curve_start_m[1] - (500.0 - R * math.sin(a))) < 1e-9
    assert abs(prof.curve_end_m[1] - (500.0 + R * math.sin(a))) < 1e-9
    assert abs(prof.curve_length_m[1] - 2 * R * a) < 1e-9
    H, dH, d2H = prof.evaluate(np.array([500.0, 400.0, 600.0, 100.0]))
    assert abs(H[0] - (7.5 - R * (1 / math.cos(a) - 1))) < 1e-9
    assert abs(H[1] - H[2]) < 1e-12 and dH[0] == 0.0 and abs(d2H[0] + 1 / R) < 1e-15
    # a point of the arc lies on the circle: centre straight below/above the PVI
    centre_h = 7.5 - R / math.cos(a)
    assert abs(math.hypot(400.0 - 500.0, H[1] - centre_h) - R) < 1e-9
    assert H[3] == 1.5 and dH[3] == g
    # a sag: the same numbers mirrored
    sag = VerticalProfile.from_pvis([0.0, 500.0, 1000.0], [0.0, -7.5, 0.0], [0.0, 0.0, 0.0],
                                    [0.0, R, 0.0])
    assert abs(sag.evaluate(500.0)[0] + H[0]) < 1e-12


def test_cant_linear_in_height_and_constant_outside():
    # 0 -> 180 mm over b = 1.5 m on a 60 m ramp, as a design tool ramps it: the height is linear
    b, h = 1.5, 0.180
    top = np.arcsin(h / b)
    cant = CantProfile.from_stations([200.0, 260.0, 850.0, 910.0], [0.0, top, top, 0.0])
    s = np.array([0.0, 200.0, 215.0, 230.0, 600.0, 880.0, 2000.0])
    c, tw = cant.evaluate(s)
    np.testing.assert_allclose(b * np.sin(c), [0.0, 0.0, 0.045, 0.090, 0.180, 0.090, 0.0], rtol=0, atol=1e-15)
    # an angle linear instead was 0.163 mm high at mid-ramp
    assert abs(b * np.sin(top / 2) - 0.090) > 1.6e-4
    # rho_tw is d(cant)/ds: against a central difference of the angle
    ds = 1e-4
    num = (cant.evaluate(s + ds)[0] - cant.evaluate(s - ds)[0]) / (2 * ds)
    inner = np.array([False, False, True, True, True, True, False])
    np.testing.assert_allclose(tw[inner], num[inner], rtol=1e-7, atol=1e-12)
    assert tw[0] == 0.0 and tw[-1] == 0.0 and tw[1] == pytest.approx(h / 60.0 / b)


def test_shapes_and_scalar():
    al = demo_like()
    r = al.evaluate(np.full((3, 4), 1500.0))
    assert r.E_m.shape == (3, 4) and r.rho_tw_1_m.shape == (3, 4)
    r0 = al.evaluate(1500.0)
    assert np.shape(r0.E_m) == () and abs(float(r0.E_m) - r.E_m[0, 0]) == 0.0


def test_invalid_inputs_raise():
    with pytest.raises(ValueError):
        Line(0.0)
    with pytest.raises(ValueError):
        Arc(10.0, float("nan"))
    with pytest.raises(ValueError):
        VerticalProfile.from_pvis([0, 100, 200], [0, 1, 0], [0, 250, 0])  # past the ends
    with pytest.raises(ValueError):
        VerticalProfile.from_pvis([0, 100, 150, 300], [0, 1, 0, 1], [0, 80, 80, 0])  # overlap
    with pytest.raises(ValueError):
        VerticalProfile.from_pvis([0, 100], [0, 1], [10, 0])  # curve at the first PVI
    with pytest.raises(ValueError):
        CantProfile.from_stations([0, 0], [0, 0.1])


@settings(max_examples=40, deadline=None)
@given(st.floats(1000.0, 2300.0), st.sampled_from(["E", "heading", "rho_h", "H", "slope", "cant"]))
def test_derivatives_are_consistent(s, which):
    """Central differences of the returned quantities agree with the returned derivatives."""
    al = demo_like()
    h = 1e-3
    breaks = np.concatenate([al.horizontal.element_chainage_m, al.profile.curve_start_m,
                             al.profile.curve_end_m, al.cant.chainage_m])
    if np.min(np.abs(breaks - s)) < 2 * h:
        s += 5 * h  # a derivative jumps at a break: step off it
    r = al.evaluate(np.array([s - h, s, s + h]))
    d = lambda x: (x[2] - x[0]) / (2 * h)  # noqa: E731
    if which == "E":
        # grid values ~3e6 m round at 5e-10 m: a longer step for positions (E''' ~ rho^2)
        hp = 0.1
        if np.min(np.abs(breaks - s)) < 2 * hp:
            s += 3 * hp
            r = al.evaluate(np.array([s - h, s, s + h]))
        rp = al.evaluate(np.array([s - hp, s + hp]))
        assert abs((rp.E_m[1] - rp.E_m[0]) / (2 * hp) - math.sin(r.heading_rad[1])) < 2e-8
        assert abs((rp.N_m[1] - rp.N_m[0]) / (2 * hp) - math.cos(r.heading_rad[1])) < 2e-8
    elif which == "heading":
        assert abs(d(np.unwrap(r.heading_rad)) - r.rho_h_1_m[1]) < 1e-10
    elif which == "rho_h":
        assert abs(d(r.rho_h_1_m) - r.drho_h_ds_1_m2[1]) < 1e-12
    elif which == "H":
        assert abs(d(r.H_m) - math.tan(r.slope_rad[1])) < 1e-9
    elif which == "slope":
        assert abs(d(r.slope_rad) - r.rho_v_1_m[1]) < 1e-10
    else:
        assert abs(d(r.cant_rad) - r.rho_tw_1_m[1]) < 1e-12


_curv = st.one_of(st.just(0.0), st.floats(1 / 20000, 1 / 150), st.floats(-1 / 150, -1 / 20000))


@settings(max_examples=50, deadline=None)
@given(st.floats(2.0, 400.0), _curv, _curv, st.floats(0.05, 0.95), st.floats(0.0, 2 * math.pi))
def test_splitting_an_element_changes_nothing(L, k0, k1, frac, h0):
    """A clothoid (or arc) cut in two at any point is the same curve: an identity that the
    Fresnel form must satisfy for any start curvature, including both ends curved."""
    a = frac * L
    km = k0 + (k1 - k0) * frac
    if k0 == k1 == 0.0:
        whole, parts = [Line(L)], [Line(a), Line(L - a)]
    elif k0 == k1:
        whole, parts = [Arc(L, k0)], [Arc(a, k0), Arc(L - a, k0)]
    else:
        whole, parts = [Clothoid(L, k0, k1)], [Clothoid(a, k0, km), Clothoid(L - a, km, k1)]
    h1 = HorizontalAlignment.from_elements(400000.0, 5000000.0, h0, whole)
    h2 = HorizontalAlignment.from_elements(400000.0, 5000000.0, h0, parts)
    s = np.linspace(-5.0, L + 5.0, 41)
    r1, r2 = h1.evaluate(s), h2.evaluate(s)
    assert np.max(np.hypot(r1.E_m - r2.E_m, r1.N_m - r2.N_m)) < 1e-8
    dh = np.angle(np.exp(1j * (r1.heading_rad - r2.heading_rad)))
    assert np.max(np.abs(dh)) < 1e-12
    np.testing.assert_allclose(r1.rho_h_1_m, r2.rho_h_1_m, rtol=0, atol=1e-15)


@settings(max_examples=40, deadline=None)
@given(st.floats(-math.pi, math.pi), _curv, _curv, st.floats(10.0, 300.0))
def test_rotating_the_start_rotates_the_curve(alpha, k0, k1, L):
    """Turning the start bearing by alpha turns every point about the start by alpha."""
    el = Clothoid(L, k0, k1) if k0 != k1 else (Arc(L, k0) if k0 else Line(L))
    h1 = HorizontalAlignment.from_elements(0.0, 0.0, 0.4, [el])
    h2 = HorizontalAlignment.from_elements(0.0, 0.0, 0.4 + alpha, [el])
    s = np.linspace(0.0, L, 17)
    z1 = h1.evaluate(s).N_m + 1j * h1.evaluate(s).E_m
    z2 = h2.evaluate(s).N_m + 1j * h2.evaluate(s).E_m
    assert np.max(np.abs(z1 * np.exp(1j * alpha) - z2)) < 1e-9
