"""Forward filter, RTS (filterpy) and two-filter smoother agree; gating keeps rejected fixes."""
import numpy as np
from hypothesis import given, settings, strategies as st

from trolley import error_models as em
from trolley.smoothers import Measurements, forward_filter, rts_smooth, two_filter_smooth


def _level_problem(seed, n_nodes=61, fix_every=20):
    rng = np.random.default_rng(seed)
    v = rng.uniform(0.5, 1.5)
    psi = rng.uniform(-np.pi, np.pi)
    dt = rng.uniform(0.5, 2.0, n_nodes - 1)
    A, G = em.level_matrices(v * np.cos(psi), v * np.sin(psi))
    noise = em.ChannelNoise(rng.uniform(1e-7, 1e-5), rng.uniform(1e-6, 2e-5), rng.uniform(0, 1e-9))
    F, Q = em.van_loan(A, G, em.level_noise_psd(noise), dt)
    P0 = em.level_initial_covariance(em.InitialUncertainty(6e-4, 1e-4, 3e-3, 1e-7, 2e-7, 1e-4))
    nodes = np.arange(0, n_nodes, fix_every)
    z = rng.normal(0, 6e-4, (len(nodes), 2)) + np.outer(np.arange(len(nodes)), rng.normal(0, 2e-3, 2))
    meas = Measurements(nodes, z, em.LEVEL_H, np.eye(2) * 6e-4**2)
    return F, Q, P0, meas


@given(seed=st.integers(0, 10_000))
@settings(max_examples=25, deadline=None)
def test_rts_equals_two_filter(seed):
    F, Q, P0, meas = _level_problem(seed)
    fwd = forward_filter(F, Q, np.zeros(5), P0, meas, gate_probability=None)
    rts = rts_smooth(F, Q, fwd, scale=np.sqrt(np.diag(P0)))
    tfs = two_filter_smooth(F, Q, meas, fwd, scale=np.sqrt(np.diag(P0)))
    sx = np.sqrt(np.diagonal(rts.P, axis1=1, axis2=2))
    # states agree to 1e-9 of their own sigma, covariances to 1e-9 relative
    assert np.max(np.abs(rts.x - tfs.x) / sx) < 1e-9
    rel = np.abs(rts.P - tfs.P) / np.sqrt(np.einsum("kii,kjj->kij", rts.P, rts.P))
    assert np.max(rel) < 1e-9


def test_smoother_is_consistent_on_simulated_truth():
    # simulate the linear model itself and check the smoothed errors are within their sigmas
    rng = np.random.default_rng(3)
    A, G = em.vertical_matrices(1.0)
    noise = em.ChannelNoise(em_arw := 2e-6, 0.0)
    F1, Q1 = em.van_loan(A, G, em.vertical_noise_psd(noise), 1.0)
    K = 241
    F = np.repeat(F1[None], K - 1, 0)
    Q = np.repeat(Q1[None], K - 1, 0)
    P0 = np.diag([6e-4**2, 1e-4**2, 3e-7**2])
    ratios = []
    for trial in range(40):
        x = rng.multivariate_normal(np.zeros(3), P0)
        xs = [x]
        for k in range(K - 1):
            x = F1 @ x + rng.multivariate_normal(np.zeros(3), Q1 + 1e-40 * np.eye(3))
            xs.append(x)
        xs = np.array(xs)
        nodes = np.arange(0, K, 60)
        z = xs[nodes, :1] + rng.normal(0, 6e-4, (len(nodes), 1))
        meas = Measurements(nodes, z, em.VERTICAL_H, np.array([[6e-4**2]]))
        fwd = forward_filter(F, Q, np.zeros(3), P0, meas, gate_probability=None)
        sm = rts_smooth(F, Q, fwd)
        ratios.append((sm.x[:, 0] - xs[:, 0]) / np.sqrt(sm.P[:, 0, 0]))
    r = np.array(ratios)
    rms = np.sqrt(np.mean(r**2))
    assert 0.8 < rms < 1.2, rms


def test_gate_rejects_outlier_and_keeps_it():
    F, Q, P0, meas = _level_problem(1)
    meas.z[1] += np.array([0.05, 0.0])  # 50 mm blunder on the second fix
    fwd = forward_filter(F, Q, np.zeros(5), P0, meas, gate_probability=0.9999)
    assert not fwd.accepted[1]
    assert fwd.accepted[[0, 2]].all()
    assert fwd.nis[1] > 100
    forced = forward_filter(F, Q, np.zeros(5), P0, meas, gate_probability=0.9999,
                            force_accept=np.array([False, True, False, False]))
    assert forced.accepted[1]
    # a forced blunder corrupts the state: the next fixes then fail the gate, as they should
    assert not forced.accepted[2:].all()


def test_both_smoothers_match_40_digit_arithmetic():
    mp = __import__("mpmath")
    mp.mp.dps = 40
    F, Q, P0, meas = _level_problem(0)
    fwd = forward_filter(F, Q, np.zeros(5), P0, meas, gate_probability=None)
    scale = np.sqrt(np.diag(P0))
    rts = rts_smooth(F, Q, fwd, scale=scale)
    tfs = two_filter_smooth(F, Q, meas, fwd, scale=scale)
    M = lambda a: mp.matrix(a.tolist())  # noqa: E731
    K = F.shape[0] + 1
    H, R, nodes = M(meas.H[0]), M(meas.R[0]), set(meas.node.tolist())
    P, Pf, Pp = M(P0), [], []
    for k in range(K):
        if k > 0:
            P = M(F[k - 1]) * P * M(F[k - 1]).T + M(Q[k - 1])
        Pp.append(P)
        if k in nodes:
            S = H * P * H.T + R
            P = (mp.eye(5) - P * H.T * S**-1 * H) * P
        Pf.append(P)
    Ps = [None] * K
    Ps[-1] = Pf[-1]
    for k in range(K - 2, -1, -1):
        C = Pf[k] * M(F[k]).T * Pp[k + 1] ** -1
        Ps[k] = Pf[k] + C * (Ps[k + 1] - Pp[k + 1]) * C.T
    ref = np.array([np.array(p.tolist(), dtype=float) for p in Ps])
    nrm = np.sqrt(np.einsum("kii,kjj->kij", ref, ref))
    assert np.max(np.abs(rts.P - ref) / nrm) < 1e-9
    assert np.max(np.abs(tfs.P - ref) / nrm) < 1e-9
