"""The bogie design model (trolley.inservice.bogie) and the sigma of the band-passed alignment
(estimator.band_alignment): hand calculations, the delay approximant against exp(-i w T), filter and
band sigma on data from their own models and the model file (the identification of both models:
test_inservice_estimator.py)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.signal import lsim

import trolley.inservice.estimator as est_mod
from survey.inservice_model import read_model, write_model
from trolley.bands import bandpass_wavelength
from trolley.inservice.bogie import XI_POS, BogieParameters, matrices, pade_delay, state_space
from trolley.inservice.estimator import (NoiseDensities, band_alignment, discrete_model, estimate,
                                         observability_rank)
from trolley.inservice.identification import EstimatorModel
from trolley.inservice.model import ModelParameters

B = BogieParameters()


@pytest.mark.parametrize("order, wt, tol", [(5, 1.0, 1e-9), (5, 3.0, 2e-5), (5, 5.4, 6e-3), (3, 1.0, 2e-5)])
def test_pade_delay_matches_exp_minus_i_omega_t(order, wt, tol):
    T = 0.128                                    # 2a / V of the default bogie at 20 m/s
    A, Bv, C, D = pade_delay(T, order)
    w = wt / T
    H = C @ np.linalg.solve(1j * w * np.eye(len(Bv)) - A, Bv) + D
    assert abs(H - np.exp(-1j * wt)) < tol
    assert C @ np.linalg.solve(-A, Bv) + D == pytest.approx(1.0, abs=1e-12)     # unit DC gain


def test_pade_delay_delays_a_smooth_signal():
    T = 0.128
    A, Bv, C, D = pade_delay(T, 5)
    t = np.arange(0, 4, 0.001)
    u = np.sin(2 * np.pi * 1.0 * t) * (t > 1) * (1 - np.cos(np.pi * np.clip(t - 1, 0, 1))) / 2
    _, y, _ = lsim((A, Bv[:, None], C[None, :], [[D]]), u, t)
    assert np.max(np.abs(y - np.interp(t - T, t, u))) < 1e-3


def test_bogie_modes_without_contact_match_hand_calculations():
    # no creep, no conicity, no damping, free wheelset yaw (kx = 0) and free frame yaw (k_yaw_s = 0):
    # * antisymmetric lateral (y1 = -y2 = u, frame yaw th): energy 2 ky (u - a th)^2 between masses 2m
    #   (u) and If / a^2 (a th): w^2 = 4 ky (1 / (2 m) + a^2 / If);
    # * symmetric lateral (y1 = y2 = u): a chain 2m -[4 ky]- mf -[ky_s]- mb, whose frequencies are the
    #   roots of the cubic det(K - w^2 M) = 0 written out by hand below;
    # * everything else (wheelset yaws, rigid yaw, rigid sway) is at zero frequency.
    p = replace(B, f11=0.0, f22=0.0, conicity=0.0, kx=0.0, k_yaw_s=0.0, cx=0.0, cy=0.0, c_yaw_s=0.0, cy_s=0.0,
                m=1500.0, mf=2500.0, mb=15000.0, If=3000.0, a=1.25, ky=4.0e6, ky_s=3.0e5)
    w_anti = np.sqrt(4 * p.ky * (1 / (2 * p.m) + p.a ** 2 / p.If))
    m1, m2, m3, k1, k2 = 2 * p.m, p.mf, p.mb, 4 * p.ky, p.ky_s
    # det [[k1 - m1 x, -k1, 0], [-k1, k1 + k2 - m2 x, -k2], [0, -k2, k2 - m3 x]] = -x (a x^2 - b x + c)
    a = m1 * m2 * m3
    b = k1 * m3 * (m1 + m2) + k2 * m1 * (m2 + m3)
    c = k1 * k2 * (m1 + m2 + m3)
    x = np.sort([(b - np.sqrt(b * b - 4 * a * c)) / (2 * a), (b + np.sqrt(b * b - 4 * a * c)) / (2 * a)])
    hand = np.sort(np.r_[np.sqrt(x), w_anti]) / (2 * np.pi)
    M, C, K, *_ = matrices(p, 20.0)
    lam = np.linalg.eigvals(np.linalg.solve(M, K))
    f = np.sort(np.sqrt(np.abs(lam[np.abs(lam) > 1e-6]))) / (2 * np.pi)
    assert np.allclose(f, hand, rtol=1e-9), (f, hand)
    assert np.sum(np.abs(lam) <= 1e-6) == 4


def test_bogie_model_keeps_the_paper_states_first_and_is_observable():
    Fc, Bc, Hc, Dc = state_space(B, 20.0)
    n = B.n_state
    assert Fc.shape == (n, n) == (20, 20) and XI_POS == 6
    assert np.all(Fc[XI_POS] == 0)                              # xi is a random walk (Eq. 10)
    assert np.all(np.real(np.linalg.eigvals(Fc)) < 1e-9)         # stable at 20 m/s (xi: a zero)
    dm = discrete_model(B, 20.0, 0.005)
    assert observability_rank(dm.F, dm.H) == n
    assert observability_rank(dm.F, dm.H[:3]) == n - 1           # without xi = 0: a common offset


def test_bogie_gravitational_stiffness_and_a_uniform_shift_of_track_and_vehicle_loads_nothing():
    # shifting the whole vehicle and the track (both xi) sideways by the same amount: no force
    M, C, K, Kd1, Kd2, _ = matrices(B, 20.0)
    q = np.array([1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0])
    assert np.allclose(K @ q - Kd1 - Kd2, 0.0, atol=1e-6 * np.abs(K).max())
    assert Kd1[0] == pytest.approx((B.m + (B.mf + B.mb) / 2) * 9.80665 * B.conicity / B.l)


def _own_model_run(p, n, seed, dt=0.005, V=20.0, xi_density=1e-7, roll_density=2e-8):
    """A run of design model ``p`` itself (process noise drawn from its own Q, sensor noise of Munoz
    2021 Sec. V); ``roll_density`` drives the roll of a model with sensor_gravity."""
    rng = np.random.default_rng(seed)
    noise = NoiseDensities(force_m2_s3=1e-3, yaw_rad2_s3=1e-4, xi_m2_per_m=xi_density, sigma_xi_virtual_m=10.0,
                           roll_rad2_per_m=roll_density)
    dm = discrete_model(p, V, dt, noise=noise)
    ns = dm.F.shape[0]
    w, U = np.linalg.eigh(dm.Q)
    L = U * np.sqrt(np.clip(w, 0, None))
    X = np.zeros((n, ns))
    e = rng.standard_normal((n, ns)) @ L.T
    for k in range(1, n):
        X[k] = dm.F @ X[k - 1] + e[k]
    Z = X @ dm.H[:3].T + rng.standard_normal((n, 3)) * np.array([0.01, 5e-4, 0.01])
    t = np.arange(n) * dt
    return t, V * t, X, Z, noise


def test_bogie_filter_on_its_own_model_has_errors_within_sigma():
    sq = []
    for seed in range(4):
        t, s, X, Z, noise = _own_model_run(B, 1500, seed)
        e = estimate(B, t, s, 20.0, Z, noise=noise, initial_covariance=np.eye(B.n_state) * 1e-14)
        sq.append(((e.x - X)[100:, :7] / e.sigma[100:, :7]) ** 2)
    nees = np.sqrt(np.mean(np.concatenate(sq), axis=0))
    assert np.all((nees > 0.75) & (nees < 1.3)), nees


@pytest.mark.parametrize("smoother", ["rts", "none"])
def test_band_sigma_is_the_spread_of_the_band_passed_error(smoother):
    # the sigma of the 3-200 m band-passed alignment against the actual band-passed errors on data
    # from the filter's own model, pooled over runs; the unfiltered sigma would be far too large there
    P = ModelParameters()
    ratio, unfiltered = [], []
    for seed in range(8):
        t, s, X, Z, noise = _own_model_run(P, 2400, seed, xi_density=4e-8)
        e = estimate(P, t, s, 20.0, Z, noise=noise, smoother=smoother, initial_covariance=np.eye(7) * 1e-14)
        g, xb, sb, tb = band_alignment(e, 3.0, 200.0, truth_m=X[:, 6])
        ratio.append((xb - tb) / sb)
        unfiltered.append(np.median(e.sigma_alignment_m) / np.median(sb))
        # the band-passed truth is exactly trolley.bands' filter of the truth on the grid
        assert np.allclose(tb, bandpass_wavelength(np.interp(g, s, X[:, 6]), g[1] - g[0], 3.0, 200.0))
    r = np.sqrt(np.mean(np.concatenate(ratio) ** 2))
    assert 0.8 < r < 1.25, r
    assert min(unfiltered) > 2.0, unfiltered


def test_band_sigma_in_blocks_agrees_with_one_block(monkeypatch):
    P = ModelParameters()
    t, s, X, Z, noise = _own_model_run(P, 9000, 11, xi_density=4e-8)       # 900 m
    e = estimate(P, t, s, 20.0, Z, noise=noise, initial_covariance=np.eye(7) * 1e-14)
    g, x1, s1 = band_alignment(e, 3.0, 70.0)
    monkeypatch.setattr(est_mod, "BAND_BLOCK_M", 150.0)
    g2, x2, s2 = band_alignment(e, 3.0, 70.0)
    assert np.array_equal(g, g2)
    # two long wavelengths of margin: the D1-D2 filter has forgotten the window ends; within one long
    # wavelength of the record's ends the two windows' own detrending shows (the sigma there is small,
    # and estimate and sigma come from the same operator either way)
    inner = (g > g[0] + 70.0) & (g < g[-1] - 70.0)
    assert np.max(np.abs(s2 / s1 - 1)[inner]) < 0.01
    assert np.max(np.abs(x2 - x1)[inner]) < 0.02 * np.std(x1)
    assert np.max(np.abs(s2 / s1 - 1)) < 0.1


def test_bogie_model_file_round_trip(tmp_path):
    n = B.n_state
    rng = np.random.default_rng(1)
    A = rng.standard_normal((n, n)) * 1e-6
    m = EstimatorModel(B.with_opt([2e7, 1e4, 4e6, 100.0]), A @ A.T, np.diag([1e-4, 2.5e-7, 1e-4, 0.09]), 0.005,
                       1.01, 1.0, 8.0, 0.36, rng.standard_normal((n, 4)) * 1e-9)
    write_model(tmp_path / "model.toml", m)
    assert 'kind = "bogie"' in (tmp_path / "model.toml").read_text()
    r = read_model(tmp_path / "model.toml")
    assert r.params == m.params and np.array_equal(r.Q, m.Q) and np.array_equal(r.S, m.S)
    assert r.params.n_state == n


def test_band_error_covariance_is_the_band_sigma_and_sets_the_spread_of_honesty():
    # its diagonal is band_alignment's sigma^2; drawing errors from it, the rms(error/sigma) of one
    # record scatters as a chi distribution with about the effective number of samples
    P = ModelParameters()
    t, s, X, Z, noise = _own_model_run(P, 2400, 2, xi_density=4e-8)
    e = estimate(P, t, s, 20.0, Z, noise=noise, initial_covariance=np.eye(7) * 1e-14)
    g, cov = est_mod.band_error_covariance(e, 3.0, 200.0, sigma_scale=1.3)
    g2, _, sb = band_alignment(e, 3.0, 200.0, sigma_scale=1.3)
    assert np.array_equal(g, g2)
    assert np.allclose(np.sqrt(np.diag(cov)), sb, rtol=1e-6, atol=1e-12)
    neff, p_h, p_j = est_mod.honesty_spread(cov, j_limit_m=np.sqrt(np.mean(np.diag(cov))))
    assert 1.0 < neff < len(g)
    # a chi^2 with neff degrees of freedom puts rms(error/sigma) in 0.7-1.3 with about this probability
    from scipy.stats import chi2
    p_chi = chi2.cdf(1.3 ** 2 * neff, neff) - chi2.cdf(0.7 ** 2 * neff, neff)
    assert p_h == pytest.approx(p_chi, abs=0.08)
    assert 0.3 < p_j < 0.8          # J at most its own rms value: about half the records
    # an identity covariance (independent samples): the rms of n = 400 unit normals is 1 +- 0.035
    neff, p_h, _ = est_mod.honesty_spread(np.eye(400))
    assert neff == pytest.approx(400) and p_h > 0.999


@pytest.mark.parametrize("smoother", ["rts", "none"])
def test_coarse_covariance_with_a_shorter_last_step_is_the_sample_recursion(smoother):
    # (bug hunt 2026-11-26) a record whose length is no whole number of grid steps: the last
    # step of idx is shorter, and the batched products ran past the record's end (IndexError on
    # a 391 m run at 17 m/s). Against the recursion sample by sample (Rauch et al. 1965)
    from trolley.inservice.estimator import _coarse_alignment_covariance
    from trolley.inservice.model import XI_INDEX

    P = ModelParameters()
    t, s, X, Z, noise = _own_model_run(P, 403, 1, xi_density=4e-8)
    e = estimate(P, t, s, 20.0, Z, noise=noise, smoother=smoother, initial_covariance=np.eye(7) * 1e-10)
    idx = np.unique(np.r_[np.arange(0, len(s), 5), len(s) - 1])
    assert idx[-1] - idx[-2] == 2
    got = _coarse_alignment_covariance(e, idx)
    n, T, Pxi = len(s), e.transitions, e.cov_xi
    full = np.zeros((n, n))
    for j in range(n):
        W = Pxi[j].copy()
        full[j, j] = W[XI_INDEX]
        if smoother == "rts":      # Cov(e_k, e_j) = C_k ... C_(j-1) P_j, k < j
            for k in range(j - 1, -1, -1):
                W = T[k] @ W
                full[k, j] = full[j, k] = W[XI_INDEX]
        else:                      # Cov(e_i, e_j) = A_i ... A_(j+1) P_j, i > j
            for i in range(j + 1, n):
                W = T[i] @ W
                full[i, j] = full[j, i] = W[XI_INDEX]
    want = full[np.ix_(idx, idx)]
    assert np.allclose(got, want, rtol=1e-9, atol=1e-12 * np.max(np.abs(want)))


@pytest.mark.parametrize("ahead_waves", [None, 0.0])
def test_estimate_in_blocks_agrees_with_the_whole_record(ahead_waves, monkeypatch):
    # (review 26: memory grew with the record's length) the forward filter runs on, the smoother and
    # the band sigma run per band block over its window; against the smoother of the whole record
    # with the same band blocks, the band-passed estimate and sigma and the unfiltered ones agree
    # (ahead_waves 0: the last block's smoother ended at the grid's last point, a few samples short
    # of the record's end, and the block's samples did not fit: a shape error)
    if ahead_waves is not None:
        monkeypatch.setattr(est_mod, "SMOOTHER_AHEAD_WAVES", ahead_waves)
    P = ModelParameters()
    t, s, X, Z, noise = _own_model_run(P, 6000, 3, xi_density=4e-8)        # 600 m
    kw = dict(noise=noise, initial_covariance=np.eye(7) * 1e-14)
    e = estimate(P, t, s, 20.0, Z, **kw)
    g, xb, sb, tb = band_alignment(e, 3.0, 70.0, sigma_scale=1.3, truth_m=X[:, 6], block_m=150.0)
    pr = est_mod.estimate_in_blocks(P, t, s, 20.0, Z, (3.0, 70.0), 1.3, X[:, 6], block_m=150.0, **kw)
    assert pr.blocks == 4          # 0-150-300-450-600 m
    g2, xb2, sb2, tb2 = pr.band
    assert np.array_equal(g, g2) and np.array_equal(tb, tb2)
    assert np.max(np.abs(xb2 - xb) / sb) < 0.01 and np.max(np.abs(sb2 / sb - 1)) < 0.01
    assert np.all(np.isfinite(pr.alignment_m)) and np.all(np.isfinite(pr.sigma_alignment_m))
    assert np.max(np.abs(pr.alignment_m - e.alignment_m) / e.sigma_alignment_m) < 0.05
    assert np.max(np.abs(pr.sigma_alignment_m / e.sigma_alignment_m - 1)) < 0.01
    assert np.array_equal(pr.normalized_innovations, e.normalized_innovations)
    # one block is estimate + band_alignment themselves
    one = est_mod.estimate_in_blocks(P, t, s, 20.0, Z, (3.0, 70.0), 1.3, X[:, 6], block_m=500.0, **kw)
    assert one.blocks == 1 and np.array_equal(one.alignment_m, e.alignment_m)
    assert np.array_equal(one.band[2], band_alignment(e, 3.0, 70.0, sigma_scale=1.3, block_m=500.0)[2])
