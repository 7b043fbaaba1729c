"""Error models of Jiang 2017: exact discretisation, observability, closed-form transitions."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from trolley import error_models as em


@given(v=st.floats(0.1, 3.0), dt=st.floats(0.01, 100.0))
@settings(max_examples=40, deadline=None)
def test_vertical_transition_matches_eq31(v, dt):
    A, G = em.vertical_matrices(v)
    F, _ = em.van_loan(A, G, np.diag([1e-12, 0.0]), dt)
    expected = np.array([[1, v * dt, -0.5 * v * dt**2], [0, 1, -dt], [0, 0, 1]])
    assert np.allclose(F, expected, rtol=1e-10, atol=1e-12)


@given(v=st.floats(0.1, 3.0), psi=st.floats(-np.pi, np.pi), dt=st.floats(0.01, 100.0))
@settings(max_examples=40, deadline=None)
def test_level_transition_matches_eq41(v, psi, dt):
    A, G = em.level_matrices(v * np.cos(psi), v * np.sin(psi))
    F, _ = em.van_loan(A, G, np.zeros((3, 3)), dt)
    c, s, t = np.cos(psi), np.sin(psi), dt
    expected = np.array([
        [1, 0, v * t * c, v * t * s, -0.5 * v * t**2 * s],
        [0, 1, v * t * s, -v * t * c, 0.5 * v * t**2 * c],
        [0, 0, 1, 0, 0], [0, 0, 0, 1, -t], [0, 0, 0, 0, 1]])
    assert np.allclose(F, expected, rtol=1e-10, atol=1e-10)


@given(v=st.floats(0.1, 3.0), dt=st.floats(0.1, 100.0))
@settings(max_examples=30, deadline=None)
def test_vertical_process_noise_closed_form(v, dt):
    # Jiang 2017 Eq. 33 with P(0)=0: the ARW terms sigma^2 v^2 t^3/3, sigma^2 v t^2/2, sigma^2 t
    q = 2.0e-6**2
    A, G = em.vertical_matrices(v)
    _, Qd = em.van_loan(A, G, np.diag([q, 0.0]), dt)
    assert np.isclose(Qd[0, 0], q * v**2 * dt**3 / 3, rtol=1e-9)
    assert np.isclose(Qd[0, 1], q * v * dt**2 / 2, rtol=1e-9)
    assert np.isclose(Qd[1, 1], q * dt, rtol=1e-9)
    assert abs(Qd[2, 2]) < 1e-30


def test_van_loan_is_batched():
    v = np.array([0.5, 1.0, 2.0])
    A, G = em.vertical_matrices(v)
    F, Qd = em.van_loan(A, G, np.diag([1e-10, 1e-16]), np.array([1.0, 2.0, 3.0]))
    for i, (vi, dti) in enumerate(zip(v, [1.0, 2.0, 3.0])):
        Fi, Qi = em.van_loan(em.vertical_matrices(vi)[0], G, np.diag([1e-10, 1e-16]), dti)
        assert np.allclose(F[i], Fi) and np.allclose(Qd[i], Qi, rtol=1e-12, atol=0)


def test_observability_ranks_eq26():
    assert em.observability_ranks(1.0, 0.3) == (3, 5)
    assert em.observability_ranks(0.7, 0.0) == (3, 5)
    # standing still: the position alone is observed (Eq. 26 with v = 0: [H; H A] = [H; 0])
    assert em.observability_ranks(0.0, 0.3) == (1, 2)


def test_interval_observability_is_the_worst_interval():
    # by hand: vertical [H; HA; HA^2] = [[1, 0, 0], [0, v, 0], [0, 0, -v]]: rank 1 + 2 [v != 0];
    # level H A = [[0, 0, vn, ve, 0], [0, 0, ve, -vn, 0]] (a 2x2 block of determinant
    # -(vn^2 + ve^2)) and H A^2 = [[0, 0, 0, 0, -ve], [0, 0, 0, 0, vn]]: rank 2 + 3 [v != 0]
    assert em.interval_observability_ranks([1.0, 0.8], [0.6, 0.0], [0.8, -0.8]) == (3, 5)
    assert em.interval_observability_ranks([1.0, 0.0, 1.2], [1.0, 0.0, 0.0], [0.0, 0.0, 1.2]) == (1, 2)
    with pytest.raises(ValueError):
        em.interval_observability_ranks([], [], [])


def test_heading_error_and_equivalent_bias_hand_values():
    from trolley import units
    lat = np.deg2rad(60.0)  # cos = 1/2
    b = units.deg_h_to_rad_s(0.03)
    phi = em.heading_error_from_gyrocompassing(b, lat)
    assert np.isclose(phi, b / (units.EARTH_RATE_RAD_S * 0.5))
    # the Earth-rate projection through that heading error adds exactly the bias again
    assert np.isclose(em.equivalent_gyro_bias(b, phi, lat), 2 * b)


@given(seed=st.integers(0, 1000))
@settings(max_examples=2, deadline=None)
def test_levelled_roll_variance_matches_a_monte_carlo_of_the_gyro_drift(seed):
    # Integrate white rate noise (ARW) and a bias (constant plus a random walk) over a survey with
    # uneven stops, remove the error linearly between the stops (as the engine's levelling does)
    # and hold it after the last one: the variance across paths is the formula's. The random walk
    # starts at the last stop, so that the bias there has the sigma b the formula is given (a
    # real bias instability is stationary; a walk from the start would have grown).
    from trolley.error_models import levelled_roll_variance
    rng = np.random.default_rng(seed)
    dt, n_paths = 0.5, 3000
    t = np.arange(0.0, 400.0 + dt / 2, dt)
    stops = np.array([0.0, 90.0, 150.0, 300.0])
    N, q, b = 4e-5, 2e-6, 1.5e-5  # rad/sqrt(s), PSD root of the bias walk, bias sigma
    walk = np.cumsum(q * np.sqrt(dt) * rng.standard_normal((n_paths, t.size)), axis=1)
    walk -= walk[:, [np.searchsorted(t, 300.0)]]
    rate = b * rng.standard_normal((n_paths, 1)) + walk + N / np.sqrt(dt) * rng.standard_normal((n_paths, t.size))
    e = np.concatenate([np.zeros((n_paths, 1)), np.cumsum(rate[:, :-1] * dt, axis=1)], axis=1)
    at = np.searchsorted(t, stops)
    err = e - np.array([np.interp(t, stops, row[at]) for row in e])
    var_mc = err.var(axis=0)
    var = levelled_roll_variance(t, stops, N, q, b)
    away = np.abs(t[:, None] - stops).min(axis=1) > 5
    # 3000 paths: a sample variance is within 3 x sqrt(2 / 3000) = 7.7 % of the true one
    ratio = var_mc[away] / var[away]
    assert np.all(np.abs(ratio - 1.0) < 0.09), (ratio.min(), ratio.max())
    assert np.all(var[at] == 0.0)
    # the hand value at the middle of the 60 s interval: N^2 T / 4 + q^2 T^3 / 48
    assert np.isclose(levelled_roll_variance(np.array([120.0]), stops, N, q, b)[0],
                      N**2 * 60 / 4 + q**2 * 60**3 / 48, rtol=1e-12)
