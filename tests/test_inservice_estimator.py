"""Simplified bogie model, Kalman estimator, identification and accuracy indices of Munoz 2021."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from trolley.bands import band_gain
from trolley.inservice.accuracy import band_accuracy, honesty
from trolley.inservice.estimator import (NoiseDensities, discrete_model, estimate, innovation_rms,
                                         observability_matrix, observability_rank)
from trolley.inservice.identification import (EstimatorModel, covariances_from_residuals,
                                              cross_covariance_from_residuals, identify_suspension,
                                              model_consistency)
from trolley.inservice.model import (G_M_S2, ModelParameters, eigenfrequencies, matrices, simulate_response,
                                     state_space)

P = ModelParameters()


def test_eigenfrequencies_without_creep_match_the_two_mass_and_yaw_oscillators():
    # no creep, no damping: y and y_f are two masses (gravitational stiffness Kg on y, 2 ky between
    # them), psi a yaw oscillator of stiffness 2 kx ls^2.
    p = replace(P, f11=0.0, f22=0.0, cx=0.0, cy=0.0, m=1000.0, mf=4000.0, I=500.0, ky=2.0e6, kx=1.0e6,
                ls=1.0, conicity=0.2, l=0.75)
    kg = 5000.0 * G_M_S2 * 0.2 / 0.75            # = 13075.5 N/m
    a = 1000.0 * 4000.0                           # det(K - w^2 M) = a w^4 - b w^2 + c
    b = 1000.0 * 4.0e6 + 4000.0 * (4.0e6 + kg)
    c = kg * 4.0e6
    w2 = np.sort([(b - np.sqrt(b * b - 4 * a * c)) / (2 * a), (b + np.sqrt(b * b - 4 * a * c)) / (2 * a)])
    yaw = np.sqrt(2 * 1.0e6 / 500.0)
    hand = np.sort(np.r_[np.sqrt(w2), yaw]) / (2 * np.pi)
    modes = eigenfrequencies(p, 20.0)
    assert np.allclose([m.frequency_hz for m in modes], hand, rtol=1e-9)
    assert all(abs(m.damping_ratio) < 1e-9 for m in modes)
    # the low mode is the two bodies swaying together on the gravitational stiffness:
    # sqrt(g alpha / l) / 2 pi = 0.2574 Hz (less 0.1 % for the finite coupling); yaw sqrt(4000)/2 pi
    assert hand[0] == pytest.approx(np.sqrt(G_M_S2 * 0.2 / 0.75) / (2 * np.pi), rel=2e-3)
    assert hand[1] == pytest.approx(10.066, abs=1e-3)


def test_large_creep_gives_klingels_kinematic_frequency():
    # a free wheelset (no suspension, negligible inertia) with stiff creep rolls kinematically:
    # omega = V sqrt(alpha / (r0 l)) (Klingel)
    p = replace(P, m=1.0, I=1.0, mf=1.0, kx=0.0, cx=0.0, ky=0.0, cy=0.0, f11=1e7, f22=1e7, conicity=0.1,
                r0=0.5, l=0.75)
    V = 10.0
    f_klingel = V * np.sqrt(0.1 / (0.5 * 0.75)) / (2 * np.pi)   # 0.8219 Hz
    f = [m.frequency_hz for m in eigenfrequencies(p, V)]
    assert min(abs(np.array(f) - f_klingel)) < 1e-5 * f_klingel


def test_gravitational_stiffness_restores():
    # a wheelset shifted left of the rails is pushed back to the right (K_g > 0, see model docstring)
    M, C, K, Kd, _ = matrices(P, 20.0)
    assert K[0, 0] > 2 * P.ky and Kd[0] == pytest.approx((P.m + P.mf) * G_M_S2 * P.conicity / P.l)
    assert Kd[1] == pytest.approx(2 * P.f11 * P.l * P.conicity / P.r0)


def test_observability_rank_is_seven_and_six_without_the_virtual_measurement():
    dm = discrete_model(P, 20.0, 0.005)
    assert observability_matrix(dm.F, dm.H).shape == (28, 7)
    assert observability_rank(dm.F, dm.H) == 7
    # the accelerations see y - xi and the gyro psi: without xi = 0 a common lateral offset of y,
    # y_f and xi is invisible
    assert observability_rank(dm.F, dm.H[:3]) == 6
    # python-control builds the same matrix (imported lazily: it pulls in matplotlib)
    control = pytest.importorskip("control")
    assert np.allclose(control.obsv(dm.F, dm.H), observability_matrix(dm.F, dm.H))


def _own_model_run(n=3000, dt=0.005, V=20.0, seed=3, xi_density=1e-7):
    rng = np.random.default_rng(seed)
    noise = NoiseDensities(force_m2_s3=1e-3, yaw_rad2_s3=1e-4, xi_m2_per_m=xi_density)
    dm = discrete_model(P, V, dt, noise=noise)
    L = np.linalg.cholesky(dm.Q + 1e-30 * np.eye(7))
    X = np.zeros((n, 7))
    w = rng.standard_normal((n, 7)) @ L.T
    for k in range(1, n):
        X[k] = dm.F @ X[k - 1] + w[k]
    sig = np.array([0.01, 5e-4, 0.01])
    Z = X @ dm.H[:3].T + rng.standard_normal((n, 3)) * sig
    t = np.arange(n) * dt
    return t, V * t, X, Z, noise, dm


def test_filter_on_its_own_model_has_errors_within_sigma():
    # the errors of y and xi are correlated over seconds (few independent samples per run), so
    # the normalised squared errors are pooled over 6 runs
    sq = {"none": [], "rts": []}
    for seed in range(6):
        t, s, X, Z, noise, _ = _own_model_run(n=1500, seed=seed)
        # the data's xi is a random walk from 0, not centred on 0: no virtual measurement pull
        noise = replace(noise, sigma_xi_virtual_m=10.0)
        for smoother in sq:
            est = estimate(P, t, s, 20.0, Z, noise=noise, smoother=smoother,
                           initial_covariance=np.eye(7) * 1e-14)       # starts at rest at 0
            sq[smoother].append(((est.x - X)[100:] / est.sigma[100:]) ** 2)
    for smoother, v in sq.items():
        nees = np.sqrt(np.mean(np.concatenate(v), axis=0))
        assert np.all((nees > 0.8) & (nees < 1.25)), (smoother, nees)


def test_normalized_innovations_have_rms_one_on_the_filters_own_model():
    # with the model and the noises exactly right the innovations are white with covariance
    # H P H^T + R: rms 1 per channel (spread over 2700 samples ~0.014)
    t, s, X, Z, noise, dm = _own_model_run(n=3000, seed=11)
    est = estimate(P, t, s, 20.0, Z, noise=replace(noise, sigma_xi_virtual_m=10.0),
                   initial_covariance=np.eye(7) * 1e-14)
    nu = innovation_rms(est, skip_m=30.0)
    assert np.all(np.abs(nu[:3] - 1.0) < 0.06), nu


#: a tight Q for the SM's deterministic response (noisy_sm_run): its innovations then see the sensors
TIGHT_NOISE = NoiseDensities(force_m2_s3=1e-6, yaw_rad2_s3=1e-7, xi_m2_per_m=1e-7, sigma_xi_virtual_m=10.0)


def noisy_sm_run(seed, flip=None, n=3000, V=20.0, dt=0.005):
    """The SM's response to a random alignment (German spectrum, ``seed``) plus the sensors' white
    noise (0.01 m/s^2, 5e-4 rad/s); ``flip`` reverses one channel's sign. Returns t, xi, Z (n, 3)."""
    from trolley.inservice.irregularity import irregularity_from_psd

    t = np.arange(n) * dt
    track = irregularity_from_psd(V * n * dt, seed=seed)
    xi = np.interp(V * t, track.s_m - track.s_m[0], track.lateral_m)
    _, Z = simulate_response(P, V, t, xi)
    Z = Z[:, :3] + np.random.default_rng(seed).standard_normal((n, 3)) * [0.01, 5e-4, 0.01]
    if flip is not None:
        Z[:, flip] *= -1.0
    return t, xi, Z


@pytest.mark.parametrize("flipped", [0, 1, 2])
def test_model_consistency_flags_a_sensor_mounted_backwards(flipped):
    # filtered with a tight Q, other alignments fit the reference run's innovations within 5 %; a
    # sensor whose sign is reversed (mounted the wrong way round) raises a ratio several times
    V, dt = 20.0, 0.005

    def recording(seed, flip=None):
        t, _, Z = noisy_sm_run(seed, flip)
        return estimate(P, t, V * t, V, Z, noise=TIGHT_NOISE)

    mdl = EstimatorModel(P, discrete_model(P, V, dt, noise=TIGHT_NOISE).Q, TIGHT_NOISE.r(), dt,
                         innovation_rms=innovation_rms(recording(1))[:3])
    same = model_consistency(recording(2), mdl)
    assert same.consistent and np.all(np.abs(same.ratio - 1.0) < 0.05), same.ratio
    wrong = model_consistency(recording(2, flipped), mdl)
    assert not wrong.consistent and wrong.ratio[flipped] > 1.4 and wrong.ratio.max() > 5.0, wrong.ratio
    # the reference holds for the calibration's rate only
    assert model_consistency(same_est := recording(3), mdl.at_dt(dt / 2)) is None
    assert model_consistency(same_est, mdl.at_dt(dt * (1 + 1e-9))).consistent


def test_filter_recovers_a_harmonic_alignment_from_noise_free_sensors():
    V, dt = 20.0, 0.005
    t = np.arange(4000) * dt
    s = V * t
    xi = 1e-3 * np.sin(2 * np.pi * s / 15.0)
    _, Z = simulate_response(P, V, t, xi)
    est = estimate(P, t, s, V, Z[:, :3])
    acc = band_accuracy(s, est.alignment_m, xi, trim_m=30.0)
    assert acc["D1"].Jrel < 0.05
    # the forward filter alone lags: the smoother, using the later sensors too, is better
    fwd = band_accuracy(s, est.x_filtered[:, 6], xi, trim_m=30.0)
    assert acc["D1"].J_m < 0.5 * fwd["D1"].J_m, (acc["D1"], fwd["D1"])


def test_curved_track_input_is_removed_exactly():
    # the same alignment on a constant-curvature track: the sensors differ (centripetal
    # acceleration, steering), the estimate does not
    V, dt = 20.0, 0.005
    t = np.arange(3000) * dt
    s = V * t
    xi = 1e-3 * np.sin(2 * np.pi * s / 20.0)
    kap = np.full_like(t, 1 / 1500.0)
    _, Zs = simulate_response(P, V, t, xi)
    _, Zc = simulate_response(P, V, t, xi, curvature_1_m=kap)
    assert np.abs(Zc[:, 0] - Zs[:, 0]).max() > 1e-3
    es = estimate(P, t, s, V, Zs[:, :3])
    ec = estimate(P, t, s, V, Zc[:, :3], curvature_1_m=kap)
    assert np.abs(ec.alignment_m - es.alignment_m)[400:].max() < 2e-5


@pytest.mark.parametrize("model, true_opt, start_opt, channels, rtol", [
    ("paper", [3.0e6, 3.0e4, 1.0e6, 1.5e4], [6.0e6, 1.0e4, 2.5e6, 4.0e4], ("y_m", "psi_rad"), 2e-3),
    ("bogie", [2.0e7, 1.0e4, 5.0e6, 2.0e4], [3.0e7, 3.0e3, 3.0e6, 5.0e4], ("y_m", "psi_rad", "yf_m", "frame_ay"), 5e-3),
])
def test_identification_recovers_known_suspension(model, true_opt, start_opt, channels, rtol):
    from trolley.inservice.bogie import BogieParameters

    base = P if model == "paper" else BogieParameters()
    V, dt = 20.0, 0.01
    t = np.arange(2000) * dt
    s = V * t
    rng = np.random.default_rng(7)
    lam = np.geomspace(5, 100, 25)
    xi = (1e-3 / 5 * np.sin(2 * np.pi * s[:, None] / lam + rng.uniform(0, 2 * np.pi, lam.size))).sum(1)
    true = base.with_opt(true_opt)
    X, Z = simulate_response(true, V, t, xi)
    ref = {"y_m": X[:, 0], "psi_rad": X[:, 1], "yf_m": X[:, 2], "frame_ay": Z[:, 2]}
    ref = {("frame_ay_m_s2" if c == "frame_ay" else c): ref[c] for c in channels}
    res = identify_suspension(base.with_opt(start_opt), V, t, xi, ref)
    assert res.cost < 1e-8 < res.cost_initial
    assert np.allclose(res.params.popt, true.popt, rtol=rtol), res.params.popt


def test_covariances_from_residuals_recover_q_and_r():
    t, s, X, Z, noise, dm = _own_model_run(n=20000, dt=0.005)
    Zv = np.column_stack([Z, np.zeros(len(Z))])
    Q, R = covariances_from_residuals(dm, X, Zv)
    rel = np.sqrt(2 / len(Z))          # relative standard error of a variance estimate
    for i in range(7):
        assert Q[i, i] == pytest.approx(dm.Q[i, i], rel=5 * rel) or dm.Q[i, i] < 1e-20
    assert np.sqrt(np.diag(R)[:3]) == pytest.approx([0.01, 5e-4, 0.01], rel=5 * rel)
    assert R[3, 3] == pytest.approx(np.mean(X[:, 6] ** 2))


def _correlated_run(n, seed, dt=0.005, V=20.0):
    """Own-model run whose accelerometers see the true velocity increments of the next step: the
    SM's force noise enters the accelerometer errors too (the situation of the full-vehicle truth)."""
    t, s, X, Z, noise, dm = _own_model_run(n=n, dt=dt, V=V, seed=seed)
    v = np.zeros_like(X)
    v[1:] = X[1:] - X[:-1] @ dm.F.T
    Z = Z.copy()
    Z[:-1, 0] += v[1:, 3] / dt
    Z[:-1, 2] += v[1:, 5] / dt
    S = np.zeros((7, 4))
    S[:, 0], S[:, 2] = dm.Q[:, 3] / dt, dm.Q[:, 5] / dt
    R = np.diag([0.01 ** 2 + dm.Q[3, 3] / dt ** 2, 5e-4 ** 2, 0.01 ** 2 + dm.Q[5, 5] / dt ** 2, 10.0 ** 2])
    R[0, 2] = R[2, 0] = dm.Q[3, 5] / dt ** 2
    return t, s, X, Z, dm, S, R


def test_cross_covariance_from_residuals_recovers_s():
    t, s, X, Z, dm, S, R = _correlated_run(20000, seed=5)
    Se = cross_covariance_from_residuals(dm, X, np.column_stack([Z, np.zeros(len(Z))]))
    for i, j in ((3, 0), (5, 2), (0, 0), (5, 0)):
        se = np.sqrt(dm.Q[i, i] * R[j, j] / len(Z))       # standard error of a sample covariance
        assert abs(Se[i, j] - S[i, j]) < 5 * se, (i, j, Se[i, j], S[i, j])
    assert np.all(Se[:, 3] == 0)


def test_filter_with_correlated_noise_is_honest_and_better():
    # with S the accelerometers act kinematically on the velocities: the filter that ignores the
    # correlation (the paper's) has much larger velocity errors; with S the errors stay within sigma
    sq = {"none": [], "rts": []}
    err = {"S": [], "no S": []}
    for seed in range(6):
        t, s, X, Z, dm, S, R = _correlated_run(1500, seed=seed)
        for smoother in sq:
            est = estimate(P, t, s, 20.0, Z, Q=dm.Q, R=R, S=S, smoother=smoother,
                           initial_covariance=np.eye(7) * 1e-14)
            sq[smoother].append(((est.x - X)[100:] / est.sigma[100:]) ** 2)
            if smoother == "rts":
                err["S"].append((est.x - X)[100:])
        plain = estimate(P, t, s, 20.0, Z, Q=dm.Q, R=R, initial_covariance=np.eye(7) * 1e-14)
        err["no S"].append((plain.x - X)[100:])
    for smoother, v in sq.items():
        nees = np.sqrt(np.mean(np.concatenate(v), axis=0))
        assert np.all((nees > 0.75) & (nees < 1.3)), (smoother, nees)
    rms = {k: np.sqrt(np.mean(np.concatenate(v) ** 2, axis=0)) for k, v in err.items()}
    ratio = rms["S"] / rms["no S"]
    assert ratio[3] < 0.7 and ratio[5] < 0.3, ratio        # y', y_f' (measured 0.54, 0.16)


def test_estimator_model_at_another_rate_with_s():
    t, s, X, Z, dm, S, R = _correlated_run(10, seed=1)
    m = EstimatorModel(P, dm.Q, R, 0.005, S=S)
    h = m.at_dt(0.0025)
    JS = lambda mm: mm.S @ np.linalg.solve(mm.R, mm.S.T)       # noqa: E731
    assert np.allclose(h.S, S / 2) and np.allclose(h.Q - JS(h), (dm.Q - JS(m)) / 2, atol=1e-20)
    assert h.R[3, 3] == pytest.approx(2 * R[3, 3]) and h.R[0, 0] == R[0, 0]


def test_j_and_jrel_hand_computed():
    s = np.arange(0.0, 1200.05, 0.1)
    A, B, C = 2e-3, 0.5e-3, 3e-3
    truth = A * np.sin(2 * np.pi * s / 10.0) + C * np.sin(2 * np.pi * s / 120.0)
    est = truth + B * np.sin(2 * np.pi * s / 10.0)
    acc = band_accuracy(s, est, truth, trim_m=240.0)   # 720 m: whole periods
    assert acc["D1"].J_m == pytest.approx(B / np.sqrt(2), rel=1e-3)
    assert acc["D1"].Jrel == pytest.approx(B / A, rel=1e-3)
    assert acc["3-200"].J_m == pytest.approx(B / np.sqrt(2), rel=1e-3)
    # the 120 m wave sits near the 200 m edge: its rms is reduced by the filter's gain there
    g10, g120 = band_gain([10.0, 120.0], 0.1, 3.0, 200.0)
    assert acc["3-200"].Jrel == pytest.approx(B * g10 / np.hypot(A * g10, C * g120), rel=1e-3)
    g120 = band_gain([120.0], 0.1, 70.0, 200.0)[0]
    assert acc["D3"].J_m < 1e-3 * B and acc["D3"].rms_true_m == pytest.approx(C * g120 / np.sqrt(2), rel=1e-3)
    assert honesty([1.0, -1.0], [2.0, 0.5], [0.0, 0.0]) == pytest.approx(np.sqrt((0.25 + 4) / 2))


def test_bad_inputs_are_refused():
    t = np.arange(10) * 0.01
    with pytest.raises(ValueError, match="shape"):
        estimate(P, t, t, 20.0, np.zeros((10, 2)))
    with pytest.raises(ValueError, match="speed"):
        estimate(P, t, t, 0.0, np.zeros((10, 3)))
    with pytest.raises(ValueError, match="uniform"):
        estimate(P, t ** 2, t, 20.0, np.zeros((10, 3)))
    with pytest.raises(ValueError, match="must be > 0"):
        ModelParameters(m=0.0)
    assert state_space(P, 20.0)[0].shape == (7, 7)
