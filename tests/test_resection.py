"""Free-station resection against hand-built geometry (trolley/resection.py)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from trolley.resection import (
    OVERLAP_SIGMA_LIMIT,
    InstrumentSigmas,
    PolarModel,
    PolarObservations,
    ResectionConfig,
    ResectionError,
    fix_covariance,
    observation_jacobian,
    observations_from_station,
    overlap_check,
    point_from_observation,
    polar_covariance,
    resect,
    setup_covariance_at,
    suggest_point_to_drop,
    variance_factor,
)

STATION = np.array([500123.456, 3100456.789, 45.678])
ORIENTATION = 2.5


def cpiii_layout(station=STATION, pairs=4, spacing_m=60.0, half_width_m=3.2, offset_m=1.0):
    """Four CPIII pairs on both sides of a straight track running north-east, the station on the axis."""
    heading = np.deg2rad(35.0)
    fwd = np.array([np.sin(heading), np.cos(heading)])
    right = np.array([np.cos(heading), -np.sin(heading)])
    along = (np.arange(pairs) - (pairs - 1) / 2.0) * spacing_m
    pts, ids = [], []
    for k, s in enumerate(along):
        for side, sgn in (("L", -1.0), ("R", 1.0)):
            en = station[:2] + s * fwd + sgn * half_width_m * right + offset_m * right
            pts.append([en[0], en[1], station[2] + 0.8 * sgn - 1.2])
            ids.append(f"CP{k:02d}{side}")
    return ids, np.array(pts)


def noisy(obs: PolarObservations, sigmas: InstrumentSigmas, rng) -> PolarObservations:
    n = len(obs)
    return PolarObservations(
        np.mod(obs.hz_rad + rng.normal(0, sigmas.direction_rad, n), 2 * np.pi),
        obs.zenith_rad + rng.normal(0, sigmas.zenith_rad, n),
        obs.slope_distance_m + rng.normal(0, 1, n) * sigmas.distance_sigma_m(obs.slope_distance_m))


def test_forward_hand_computed():
    # a target 30 m east, 40 m north and 2 m up; no curvature: hz = atan2(30, 40) - orientation
    st_ = np.array([10.0, 20.0, 1.0])
    obs = observations_from_station(st_, 0.1, st_ + [30.0, 40.0, 2.0], PolarModel(curvature_refraction=False))
    assert obs.hz_rad[0] == pytest.approx(np.arctan2(30, 40) - 0.1, abs=1e-15)
    assert obs.zenith_rad[0] == pytest.approx(np.arctan2(50.0, 2.0), abs=1e-15)
    assert obs.slope_distance_m[0] == pytest.approx(np.sqrt(2504.0), abs=1e-12)
    # curvature and refraction lower a target 90 m away by (1 - 0.13) 90^2 / (2 R) = 0.55 mm
    m = PolarModel()
    flat = observations_from_station(np.zeros(3), 0.0, [0.0, 90.0, 0.0], m)
    assert 90.0 * (flat.zenith_rad[0] - np.pi / 2) == pytest.approx(0.87 * 8100 / (2 * 6.378e6), rel=1e-6)


@pytest.mark.parametrize("model", [PolarModel(), PolarModel(grid_scale=1.0 - 4e-5, refraction_k=0.2)])
def test_inverse_and_jacobian(model):
    ids, pts = cpiii_layout()
    obs = observations_from_station(STATION, ORIENTATION, pts, model)
    np.testing.assert_allclose(point_from_observation(STATION, ORIENTATION, obs, model), pts, atol=1e-8)
    j = observation_jacobian(STATION, pts, model)
    eps = 1e-4
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        plus = observations_from_station(STATION, ORIENTATION, pts + d, model).as_array()
        minus = observations_from_station(STATION, ORIENTATION, pts - d, model).as_array()
        np.testing.assert_allclose((plus - minus) / (2 * eps), j[:, :, k], rtol=1e-5, atol=1e-9)


def test_exact_observations_recover_station():
    ids, pts = cpiii_layout()
    res = resect(ids, pts, observations_from_station(STATION, ORIENTATION, pts))
    np.testing.assert_allclose(res.station_enh_m, STATION, atol=1e-8)
    assert res.orientation_rad == pytest.approx(ORIENTATION, abs=1e-11)
    assert res.dof == 24 - 4
    assert res.sigma0 < 1e-3
    assert res.flagged_points == () and suggest_point_to_drop(res) is None


def test_grid_scale_matters_and_is_modelled():
    # a 40 ppm grid scale: ignoring it moves the station; modelling it recovers the station exactly
    ids, pts = cpiii_layout()
    scaled = PolarModel(grid_scale=1.0 + 4e-5)
    obs = observations_from_station(STATION, ORIENTATION, pts, scaled)
    right = resect(ids, pts, obs, ResectionConfig(model=scaled))
    np.testing.assert_allclose(right.station_enh_m, STATION, atol=1e-8)
    wrong = resect(ids, pts, obs)
    assert wrong.sigma0 > 2.0


def test_noisy_observations_within_sigma():
    ids, pts = cpiii_layout()
    rng = np.random.default_rng(7)
    sig = InstrumentSigmas()
    chi2 = []
    for _ in range(20):
        res = resect(ids, pts, noisy(observations_from_station(STATION, ORIENTATION, pts), sig, rng))
        e = np.r_[res.station_enh_m - STATION, (res.orientation_rad - ORIENTATION + np.pi) % (2 * np.pi) - np.pi]
        chi2.append(e @ np.linalg.solve(res.covariance, e))
    # each error is ~chi2(4) in its own covariance; the sum of 20 is chi2(80)
    assert stats.chi2.ppf(1e-4, 80) < sum(chi2) < stats.chi2.ppf(1 - 1e-4, 80)
    # sub-millimetre station from 8 CPIII points, as in practice
    assert np.all(res.station_sigma_m < 0.0005)


def test_one_bad_point_is_flagged_and_dropping_it_cleans_up():
    ids, pts = cpiii_layout()
    rng = np.random.default_rng(3)
    sig = InstrumentSigmas()
    wrong = pts.copy()
    wrong[5] += [0.005 * np.cos(0.3), 0.005 * np.sin(0.3), 0.0]  # the prism is 5 mm away from its coordinates
    obs = noisy(observations_from_station(STATION, ORIENTATION, wrong), sig, rng)
    res = resect(ids, pts, obs)
    assert suggest_point_to_drop(res) == ids[5]
    assert res.residuals[5].flagged and "standardized" in res.residuals[5].reason
    assert res.sigma0 > 3.0
    # horizontal residual of the bad point: most of the 5 mm shows up there
    r5 = res.residuals[5]
    assert np.hypot(r5.across_m, r5.along_m) > 0.003
    clean = resect(ids, pts, obs, exclude=[ids[5]])
    # only noise left: no |w| beyond 4 (false-alarm chance 21 x 6e-5 ~ 0.1 %)
    assert max(r.max_standardized for r in clean.residuals) < 4.0
    assert clean.excluded == (ids[5],)
    assert len(clean.residuals) == 7
    assert clean.sigma0 < 2.0
    np.testing.assert_array_less(np.abs(clean.station_enh_m - STATION), 5 * clean.station_sigma_m)


def test_height_error_flagged_by_zenith():
    ids, pts = cpiii_layout()
    wrong = pts.copy()
    wrong[2, 2] += 0.005
    res = resect(ids, pts, observations_from_station(STATION, ORIENTATION, wrong))
    assert suggest_point_to_drop(res) == ids[2]
    assert res.residuals[2].height_m == pytest.approx(0.005, abs=0.0015)


def test_three_points_minimum_and_errors():
    ids, pts = cpiii_layout()
    obs = observations_from_station(STATION, ORIENTATION, pts[:3])
    res = resect(ids[:3], pts[:3], obs)
    np.testing.assert_allclose(res.station_enh_m, STATION, atol=1e-7)
    assert res.dof == 5
    with pytest.raises(ResectionError, match="3 distinct"):
        resect(ids[:2], pts[:2], observations_from_station(STATION, ORIENTATION, pts[:2]))
    with pytest.raises(ResectionError, match="3 distinct"):
        resect(ids[:3], pts[:3], obs, exclude=[ids[0]])
    with pytest.raises(ResectionError, match="length"):
        resect(ids[:4], pts[:3], obs)


def test_missing_distance_uses_direction_only():
    ids, pts = cpiii_layout()
    obs = observations_from_station(STATION, ORIENTATION, pts)
    obs.slope_distance_m[[1, 4]] = np.nan
    res = resect(ids, pts, obs)
    np.testing.assert_allclose(res.station_enh_m, STATION, atol=1e-7)
    assert res.dof == 22 - 4
    assert np.isnan(res.residuals[1].distance_m)


def test_metric_tolerance_flag():
    ids, pts = cpiii_layout()
    wrong = pts.copy()
    wrong[0, 2] += 0.004
    cfg = ResectionConfig(max_standardized_residual=1e9, max_point_residual_m=0.002)
    res = resect(ids, pts, observations_from_station(STATION, ORIENTATION, wrong), cfg)
    assert res.flagged_points == (ids[0],)
    assert "mm >" in res.residuals[0].reason


def test_overlap_check():
    chk = overlap_check("S12", [100.0, 200.0, 10.0], [100.0012, 199.9990, 10.0005], tolerance_m=0.002)
    np.testing.assert_allclose(chk.difference_enh_mm, [1.2, -1.0, 0.5], atol=1e-6)
    assert chk.horizontal_m == pytest.approx(np.hypot(0.0012, 0.0010))
    assert chk.within_tolerance
    assert not overlap_check("S12", [0, 0, 0], [0, 0, 0.0025]).within_tolerance


def test_overlap_of_a_trolley_point_from_two_resected_stations():
    # the same prism measured from two free stations 120 m apart agrees within the combined sigma
    rng = np.random.default_rng(11)
    sig = InstrumentSigmas()
    prism = STATION + [40.0, 30.0, 0.6]
    found = []
    for k, base in enumerate([STATION, STATION + [120 * np.sin(0.61), 120 * np.cos(0.61), 0.5]]):
        ids, pts = cpiii_layout(station=base)
        res = resect(ids, pts, noisy(observations_from_station(base, 0.7 * k, pts), sig, rng))
        o = noisy(observations_from_station(base, 0.7 * k, prism), sig, rng)
        found.append(point_from_observation(res.station_enh_m, res.orientation_rad, o)[0])
    chk = overlap_check("prism", found[0], found[1])
    assert chk.within_tolerance
    assert np.all(np.abs(chk.difference_enh_m) < 0.002)


@settings(max_examples=30, deadline=None, derandomize=True)
@given(n_points=st.integers(3, 10), seed=st.integers(0, 2**31 - 1),
       orientation=st.floats(0.0, 2 * np.pi, exclude_max=True),
       spread_deg=st.floats(120.0, 360.0))
def test_sigma0_near_one_on_correctly_weighted_noise(n_points, seed, orientation, spread_deg):
    rng = np.random.default_rng(seed)
    az = np.deg2rad(rng.uniform(0.0, spread_deg, n_points))
    r = rng.uniform(15.0, 120.0, n_points)
    pts = np.column_stack([STATION[0] + r * np.sin(az), STATION[1] + r * np.cos(az),
                           STATION[2] + rng.uniform(-3.0, 3.0, n_points)])
    ids = [f"P{i}" for i in range(n_points)]
    sig = InstrumentSigmas()
    exact = observations_from_station(STATION, orientation, pts)
    reps = 25
    vpv = 0.0
    for _ in range(reps):
        res = resect(ids, pts, noisy(exact, sig, rng))
        vpv += res.sigma0**2 * res.dof
    dof_total = reps * (3 * n_points - 4)
    # the weighted square sum of residuals is chi2(dof): sigma0^2 averages 1
    assert stats.chi2.ppf(1e-5, dof_total) < vpv < stats.chi2.ppf(1 - 1e-5, dof_total)
    s0 = np.sqrt(vpv / dof_total)
    assert 0.6 < s0 < 1.4


def test_setup_covariance_at_a_point_by_hand():
    # orientation alone, 1 arc second: a point 200 m due north moves east by 200 m x 4.85e-6 rad,
    # one 100 m east and 100 m north moves across the sight line, (+dN, -dE) d_orientation
    so = np.deg2rad(1.0 / 3600.0)
    c = np.diag([0.0, 0.0, 0.0, so**2])
    st_ = np.array([10.0, 20.0, 5.0])
    cov = setup_covariance_at(c, st_, [st_ + [0.0, 200.0, 1.0], st_ + [100.0, 100.0, -2.0]])
    np.testing.assert_allclose(cov[0], np.diag([(200 * so) ** 2, 0.0, 0.0]), atol=1e-22)
    q = (100 * so) ** 2
    np.testing.assert_allclose(cov[1], [[q, -q, 0.0], [-q, q, 0.0], [0.0, 0.0, 0.0]], atol=1e-22)
    # the station's position alone moves every point with it, whatever its distance
    c = np.diag([1e-8, 4e-8, 9e-8, 0.0])
    c[0, 1] = c[1, 0] = 1e-8
    np.testing.assert_allclose(setup_covariance_at(c, st_, st_ + [250.0, -30.0, 0.6])[0], c[:3, :3], atol=1e-22)
    # station and orientation correlated: var E = C_EE + 2 dN C_Eo + dN^2 C_oo (dE = 0, dN = 150)
    c = np.diag([1e-8, 1e-8, 1e-9, so**2])
    c[0, 3] = c[3, 0] = 0.5 * np.sqrt(1e-8) * so
    var_e = setup_covariance_at(c, st_, st_ + [0.0, 150.0, 0.0])[0][0, 0]
    assert var_e == pytest.approx(1e-8 + 2 * 150 * 0.5 * 1e-4 * so + 150**2 * so**2, rel=1e-12)


@settings(max_examples=50, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1), d_m=st.floats(1.0, 500.0), az=st.floats(0.0, 2 * np.pi))
def test_setup_covariance_orientation_adds_nothing_along_the_sight(seed, d_m, az):
    # in the line-of-sight frame the orientation moves a point across the sight only, by d x
    # d_orientation: along the sight the variance is the station's, across it that of
    # (across . dS + d d_orientation)
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(4, 4)) * np.array([1e-4, 1e-4, 1e-4, 1e-6])
    c = a @ a.T
    st_ = rng.normal(size=3) * 100.0
    p = st_ + [d_m * np.sin(az), d_m * np.cos(az), rng.normal()]
    cov = setup_covariance_at(c, st_, p)[0]
    along = np.array([np.sin(az), np.cos(az), 0.0])
    across = np.array([np.cos(az), -np.sin(az), 0.0])
    assert along @ cov @ along == pytest.approx(along @ c[:3, :3] @ along, rel=1e-9, abs=1e-24)
    g = np.r_[across, d_m]
    assert across @ cov @ across == pytest.approx(g @ c @ g, rel=1e-9, abs=1e-24)
    assert cov[2, 2] == pytest.approx(c[2, 2], rel=1e-12)


@pytest.mark.parametrize("model", [PolarModel(curvature_refraction=False),
                                   PolarModel(grid_scale=0.99961)])
def test_setup_covariance_matches_a_monte_carlo_of_resected_fixes(model):
    # a noise-free prism 250 m ahead measured from each of 1500 noisy free stations: its spread is the
    # setup error the fix carries, and it follows the propagated covariance (chi-square bounds)
    rng = np.random.default_rng(2024)
    sig = InstrumentSigmas()
    ids, pts = cpiii_layout()
    exact = observations_from_station(STATION, ORIENTATION, pts, model)
    heading = np.deg2rad(35.0)
    prism = STATION + [250.0 * np.sin(heading) + 2.0, 250.0 * np.cos(heading) - 3.0, -0.6]
    prism_obs = observations_from_station(STATION, ORIENTATION, prism, model)
    config = ResectionConfig(model=model)
    n = 1500
    err = np.empty((n, 3))
    cov = None
    for i in range(n):
        res = resect(ids, pts, noisy(exact, sig, rng), config)
        err[i] = point_from_observation(res.station_enh_m, res.orientation_rad, prism_obs, model)[0] - prism
        cov = setup_covariance_at(res.covariance, res.station_enh_m, prism)[0] if cov is None else cov
    lo, hi = np.sqrt(stats.chi2.ppf([0.0005, 0.9995], n - 1) / (n - 1))
    ratio = err.std(axis=0, ddof=1) / np.sqrt(np.diag(cov))
    assert np.all((ratio > lo) & (ratio < hi)), ratio
    # the whole 3x3 covariance, correlations included: e' C^-1 e is chi-square with 3 dof
    maha = np.einsum("ij,jk,ik->i", err, np.linalg.inv(cov), err)
    assert stats.chi2.ppf(0.0005, 3 * n) / n < maha.mean() < stats.chi2.ppf(0.9995, 3 * n) / n
    # at 250 m the orientation's part dominates across the sight: more than the station's own sigma
    across = np.array([np.cos(heading), -np.sin(heading), 0.0])
    assert np.sqrt(across @ cov @ across) > 1.5 * np.sqrt(across @ res.covariance[:3, :3] @ across)


def test_variance_factor_by_hand():
    # sigma0 above 1 scales the a priori covariance by sigma0^2; at or below 1, or without redundancy, not
    assert variance_factor(1.5, 20) == pytest.approx(2.25, rel=1e-15)
    assert variance_factor(3.0, 5) == pytest.approx(9.0, rel=1e-15)
    assert variance_factor(1.0, 20) == 1.0 and variance_factor(0.6, 20) == 1.0
    assert variance_factor(float("nan"), 0) == 1.0 and variance_factor(2.0, 0) == 1.0


def _expected_nees_scaled(ratio: float, dof: int) -> tuple[float, float]:
    """Mean and variance of e' (f C)^-1 e with f = max(1, sigma0^2) when the noise is ``ratio`` times the
    a priori: e' C^-1 e = ratio^2 chi2(4) and sigma0^2 = ratio^2 chi2(dof) / dof, independent in least
    squares, so E = 4 ratio^2 E[g] and E[.^2] = 24 ratio^4 E[g^2], g = min(1, dof / (ratio^2 X))."""
    from scipy import integrate

    def moment(p):
        return integrate.quad(lambda x: min(1.0, dof / (ratio**2 * x)) ** p * stats.chi2.pdf(x, dof), 0, np.inf,
                              limit=200)[0]

    mean = 4 * ratio**2 * moment(1)
    return mean, 24 * ratio**4 * moment(2) - mean**2


@pytest.mark.parametrize("ratio", [1.0, 2.0])
def test_setup_covariance_scaled_by_sigma0_is_honest_when_the_instrument_is_noisier(ratio):
    # 2000 resections on 8 CPIII with the readings' noise `ratio` times the a priori sigmas: at 2x the
    # a priori covariance is 2x too small in sigma (e' C^-1 e averages 16, not 4), the one scaled by
    # sigma0^2 follows the analytic law (Student-t: 4 dof / (dof - 2)); at 1x the scaling costs little
    rng = np.random.default_rng(31)
    sig = InstrumentSigmas()
    noise = InstrumentSigmas(ratio * sig.direction_rad, ratio * sig.zenith_rad, ratio * sig.distance_m,
                             ratio * sig.distance_scale)
    ids, pts = cpiii_layout()
    exact = observations_from_station(STATION, ORIENTATION, pts)
    n = 2000
    err, var_ap, var_sc, nees_ap, nees_sc = [], [], [], [], []
    for _ in range(n):
        res = resect(ids, pts, noisy(exact, noise, rng))
        e = np.r_[res.station_enh_m - STATION, (res.orientation_rad - ORIENTATION + np.pi) % (2 * np.pi) - np.pi]
        err.append(e)
        var_ap.append(np.diag(res.covariance))
        var_sc.append(np.diag(res.setup_covariance))
        nees_ap.append(e @ np.linalg.solve(res.covariance, e))
        nees_sc.append(e @ np.linalg.solve(res.setup_covariance, e))
    dof = res.dof
    assert dof == 20
    err, var_ap, var_sc = map(np.array, (err, var_ap, var_sc))
    # per component, RMS error against the RMS sigma: 1 for an honest covariance
    honest = np.sqrt(np.mean(err**2, axis=0) / np.mean(var_sc, axis=0))
    plain = np.sqrt(np.mean(err**2, axis=0) / np.mean(var_ap, axis=0))
    if ratio == 2.0:
        assert np.all(np.abs(honest - 1.0) < 0.07), honest
        assert np.all(np.abs(plain - 2.0) < 0.14), plain  # the a priori covariance: half the true sigma
    else:
        assert np.all((honest > 0.90) & (honest < 1.02)), honest  # a little conservative, never optimistic
        assert np.all(np.abs(plain - 1.0) < 0.07), plain
    # the whole covariance against the analytic mean of e' (f C)^-1 e
    mean, var = _expected_nees_scaled(ratio, dof)
    assert abs(np.mean(nees_sc) - mean) < 4 * np.sqrt(var / n), (np.mean(nees_sc), mean)
    assert abs(np.mean(nees_ap) - 4 * ratio**2) < 4 * np.sqrt(8 * ratio**4 / n)


#: 1" on both angles, 0.6 mm + 0 ppm: round figures for the hand computations below
ROUND_SIGMAS = InstrumentSigmas(direction_rad=np.deg2rad(1.0 / 3600.0), zenith_rad=np.deg2rad(1.0 / 3600.0),
                                distance_m=0.0006, distance_scale=0.0)
FLAT = PolarModel(curvature_refraction=False)


def test_fix_covariance_by_hand():
    # a horizontal line 200 m due north, 1" angles, 0.6 mm distance, and 1" of setup orientation:
    # E (across) sqrt((200 m x 1")^2 + (200 m x 1")^2), N (along) 0.6 mm, H 200 m x 1"; the
    # variance factor 2 doubles every variance
    so = np.deg2rad(1.0 / 3600.0)
    st_ = np.array([10.0, 20.0, 5.0])
    cov = fix_covariance(ROUND_SIGMAS, np.diag([0.0, 0.0, 0.0, so**2]), st_, st_ + [0.0, 200.0, 0.0], FLAT)
    assert cov.shape == (1, 3, 3)
    a = (200 * so) ** 2
    np.testing.assert_allclose(cov[0], np.diag([2 * a, 0.0006**2, a]), rtol=1e-9, atol=1e-16)
    assert np.sqrt(cov[0, 0, 0]) * 1e3 == pytest.approx(np.sqrt(2 * 0.94017), rel=1e-4)
    twice = fix_covariance(ROUND_SIGMAS, np.diag([0.0, 0.0, 0.0, so**2]), st_, st_ + [0.0, 200.0, 0.0], FLAT, 2.0)
    np.testing.assert_allclose(twice, 2 * cov, rtol=1e-12)


def test_polar_covariance_by_hand_north_and_45_degrees():
    # due north, horizontal, 260 m, 0.5" and 0.6 mm + 1 ppm: across = E = 0.5" x 260 m = 0.630 mm,
    # along = N = 0.6 + 0.26 = 0.86 mm, H = 0.5" x 260 m, no correlation
    sig = InstrumentSigmas()
    c = polar_covariance(np.zeros(3), [0.0, 260.0, 0.0], sig, FLAT)[0]
    across, along = sig.direction_rad * 260.0, 0.0006 + 1e-6 * 260.0
    assert across * 1e3 == pytest.approx(0.6303, abs=1e-4)
    np.testing.assert_allclose(c, np.diag([across**2, along**2, (sig.zenith_rad * 260.0) ** 2]),
                               rtol=1e-9, atol=1e-18)
    # the same line turned to azimuth 45 deg: the along and across variances share E and N, and the
    # E-N covariance is (along^2 - across^2) / 2
    p45 = 260.0 * np.array([np.sin(np.pi / 4), np.cos(np.pi / 4), 0.0])
    c45 = polar_covariance(np.zeros(3), p45, sig, FLAT)[0]
    half = 0.5 * (along**2 + across**2)
    np.testing.assert_allclose(c45[:2, :2], [[half, 0.5 * (along**2 - across**2)],
                                             [0.5 * (along**2 - across**2), half]], rtol=1e-9)
    assert c45[0, 1] / half == pytest.approx((0.86**2 - 0.6303**2) / (0.86**2 + 0.6303**2), rel=1e-3)


def test_polar_covariance_matches_a_monte_carlo_of_the_polar_model():
    # readings drawn with the instrument sigmas, points computed by point_from_observation (the
    # session's own computation, curvature included): their sample covariance is the propagated one;
    # 20000 draws: each element within 5 of its own standard errors (Wishart: var(s_ij) = (c_ii c_jj
    # + c_ij^2) / n)
    rng = np.random.default_rng(5)
    sig = InstrumentSigmas(distance_scale=20e-6)  # a large ppm part, so the distance's share shows
    st_ = np.array([100.0, 200.0, 10.0])
    target = st_ + [-150.0, 80.0, -12.0]
    obs = observations_from_station(st_, 0.3, target)
    n = 20000
    draws = PolarObservations(np.full(n, obs.hz_rad[0]), np.full(n, obs.zenith_rad[0]),
                              np.full(n, obs.slope_distance_m[0]))
    pts = point_from_observation(st_, 0.3, noisy(draws, sig, rng))
    c = polar_covariance(st_, target, sig)[0]
    mc = np.cov(pts.T)
    se = np.sqrt((np.outer(np.diag(c), np.diag(c)) + c**2) / n)
    assert np.all(np.abs(mc - c) < 5 * se), (mc - c) / se


@settings(max_examples=40, deadline=None)
@given(st.floats(0.0, 2 * np.pi), st.floats(2.0, 400.0), st.floats(-30.0, 30.0), st.floats(0.0, 20e-6))
def test_polar_covariance_is_the_numeric_jacobian_of_the_point_computation(az, hd, dh, ppm):
    # property: for any line, J S J^T with J the central-difference derivative of point_from_observation
    sig = InstrumentSigmas(distance_scale=ppm)
    st_ = np.array([5.0, -7.0, 2.0])
    target = st_ + [hd * np.sin(az), hd * np.cos(az), dh]
    obs = observations_from_station(st_, 0.0, target).as_array()[0]
    steps = np.array([1e-7, 1e-7, 1e-4])
    jac = np.empty((3, 3))
    for j in range(3):
        up, down = obs.copy(), obs.copy()
        up[j] += steps[j]
        down[j] -= steps[j]
        jac[:, j] = (point_from_observation(st_, 0.0, PolarObservations(*up))[0]
                     - point_from_observation(st_, 0.0, PolarObservations(*down))[0]) / (2 * steps[j])
    s = np.diag([sig.direction_rad**2, sig.zenith_rad**2, float(sig.distance_sigma_m(obs[2])) ** 2])
    np.testing.assert_allclose(polar_covariance(st_, target, sig)[0], jac @ s @ jac.T, rtol=1e-5, atol=1e-15)


def test_overlap_check_sigma_by_hand():
    # the demo's FIX013: E -0.28, N -1.07, H +2.19 mm; two positions of 0.6 mm per axis each: the
    # difference has sigma sqrt(0.36 + 0.36) = 0.8485 mm per axis, H is 2.58 sigma: outside the
    # 2 mm tolerance, within 3 sigma
    c = np.eye(3) * 0.0006**2
    chk = overlap_check("FIX012", [0.0, 0.0, 0.0], [-0.00028, -0.00107, 0.00219], 0.002, c, c)
    np.testing.assert_allclose(chk.sigma_enh_m, np.full(3, np.sqrt(0.72) * 1e-3), rtol=1e-12)
    np.testing.assert_allclose(chk.normalized, np.array([0.28, 1.07, 2.19]) / np.sqrt(0.72), rtol=1e-9)
    assert not chk.within_tolerance and chk.consistent is True
    assert chk.max_normalized == pytest.approx(2.19 / np.sqrt(0.72), rel=1e-9)
    # uncorrelated: the joint length is the root sum of squares, sqrt(0.28^2 + 1.07^2 + 2.19^2) / 0.8485
    assert chk.mahalanobis == pytest.approx(np.sqrt(0.28**2 + 1.07**2 + 2.19**2) / np.sqrt(0.72), rel=1e-9)
    # 3.0 mm is 3.54 sigma, beyond the 3.436 of chi-square (3 dof) at the old rule's 0.81 %
    assert OVERLAP_SIGMA_LIMIT == pytest.approx(np.sqrt(stats.chi2.isf(1 - (1 - 2 * stats.norm.sf(3)) ** 3, 3)))
    assert OVERLAP_SIGMA_LIMIT == pytest.approx(3.436, abs=1e-3)
    far = overlap_check("p", [0.0, 0.0, 0.0], [0.0, 0.0, 0.0030], 0.002, c, c)
    assert far.consistent is False and far.max_normalized == pytest.approx(3.0 / np.sqrt(0.72), rel=1e-9)
    # the setup parts add: a first position with 1 mm in E from its setup
    c1 = c + np.diag([1e-6, 0.0, 0.0])
    assert overlap_check("p", np.zeros(3), np.zeros(3), 0.002, c1, c).sigma_enh_m[0] == pytest.approx(
        np.sqrt(1.72) * 1e-3, rel=1e-12)
    # without covariances: no sigma, no statistical verdict
    plain = overlap_check("p", np.zeros(3), [0.0, 0.0, 0.0025])
    assert np.all(np.isnan(plain.sigma_enh_m)) and plain.consistent is None and not plain.within_tolerance
    assert np.isnan(plain.mahalanobis)
    with pytest.raises(ValueError, match="both positions or of neither"):
        overlap_check("p", np.zeros(3), np.zeros(3), 0.002, c, None)


def test_overlap_joint_test_follows_the_correlation():
    # E and N correlated 0.9 (1 mm each, H 1 mm apart): a difference of 2.5 mm in E and -2.5 mm in N is
    # 2.5 sigma on each axis, within the old per-axis 3 sigma, but it lies along the narrow diagonal
    # (variance 0.1 mm^2): joint length sqrt(12.5 / 0.1) = 11.2, far beyond; 3.2 mm in both is beyond 3
    # sigma per axis but along the wide diagonal (variance 1.9): sqrt(20.48 / 1.9) = 3.28, within
    half = 0.5e-6 * np.array([[1.0, 0.9, 0.0], [0.9, 1.0, 0.0], [0.0, 0.0, 1.0]])  # each position's
    across = overlap_check("p", np.zeros(3), [0.0025, -0.0025, 0.0], 0.002, half, half)
    assert across.max_normalized == pytest.approx(2.5, rel=1e-9) and across.max_normalized < 3.0
    assert across.mahalanobis == pytest.approx(np.sqrt(12.5 / 0.1), rel=1e-9) and across.consistent is False
    along = overlap_check("p", np.zeros(3), [0.0032, 0.0032, 0.0], 0.002, half, half)
    assert along.max_normalized == pytest.approx(3.2, rel=1e-9) and along.max_normalized > 3.0
    assert along.mahalanobis == pytest.approx(np.sqrt(20.48 / 1.9), rel=1e-9) and along.consistent is True


def test_overlap_sigma_matches_a_monte_carlo_of_two_resected_stations():
    # a prism 50 m from one free station and 90 m from the next, each on 8 noisy CPIII pointings, each
    # position measured with the instrument's noise on its own readings: the difference over 2000
    # trials follows the covariance overlap_check reports (chi-square bounds per axis), its whole
    # covariance (e' C^-1 e averages 3), and |d| > 2 sigma on an axis 4.55 % of the time
    rng = np.random.default_rng(12)
    sig = InstrumentSigmas()
    prism = STATION + [40.0, 30.0, 0.6]
    bases = [STATION, STATION + [120 * np.sin(0.61), 120 * np.cos(0.61), 0.5]]
    layouts = [cpiii_layout(station=b) for b in bases]
    exact = [observations_from_station(b, 0.7 * k, layouts[k][1]) for k, b in enumerate(bases)]
    prism_obs = [observations_from_station(b, 0.7 * k, prism) for k, b in enumerate(bases)]
    n = 2000
    z, maha = [], []
    for _ in range(n):
        pos, cov = [], []
        for k in range(2):
            res = resect(layouts[k][0], layouts[k][1], noisy(exact[k], sig, rng))
            p = point_from_observation(res.station_enh_m, res.orientation_rad, noisy(prism_obs[k], sig, rng))[0]
            pos.append(p)
            cov.append(fix_covariance(sig, res.covariance, res.station_enh_m, p)[0])
        chk = overlap_check("prism", pos[0], pos[1], 0.002, cov[0], cov[1])
        z.append(chk.difference_enh_m / chk.sigma_enh_m)
        maha.append(chk.mahalanobis ** 2)
    z = np.array(z)
    lo, hi = np.sqrt(stats.chi2.ppf([0.0005, 0.9995], n) / n)
    rms = np.sqrt(np.mean(z**2, axis=0))
    assert np.all((rms > lo) & (rms < hi)), rms
    assert stats.chi2.ppf(0.0005, 3 * n) / n < np.mean(maha) < stats.chi2.ppf(0.9995, 3 * n) / n
    p2 = 2 * stats.norm.sf(2.0)
    k_lo, k_hi = stats.binom.ppf([0.0005, 0.9995], n, p2)
    for j in range(3):
        assert k_lo <= np.sum(np.abs(z[:, j]) > 2.0) <= k_hi
    # the setups' part is in the sigma: the measurements alone would claim 3.5 % and 4.1 % less in E, N
    alone = np.sqrt(np.diag(sum(polar_covariance(b, prism, sig)[0] for b in bases)))
    assert np.all(chk.sigma_enh_m[:2] > 1.03 * alone[:2]), (chk.sigma_enh_m, alone)
