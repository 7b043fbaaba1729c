"""Forward filter, RTS (filterpy) and two-filter smoother agree; gating keeps rejected fixes."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from trolley import error_models as em
from trolley.engine import longest_run
from trolley.smoothers import (CONFIRMING_MEASUREMENTS, Measurements, confirmed_forward_filter, forward_filter,
                               rts_smooth, two_filter_smooth)


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


def _walk_problem(n_meas: int = 12, sigma: float = 0.1, q: float = 1.0):
    """A scalar random walk (step sigma q) measured every step with noise sigma << q, as a
    position fix is against the dead reckoning's error: a fix taken sets the state to itself."""
    F = np.ones((n_meas - 1, 1, 1))
    Q = np.full((n_meas - 1, 1, 1), q**2)
    meas = Measurements(np.arange(n_meas), np.zeros((n_meas, 1)), np.ones((1, 1)), np.full((1, 1), sigma**2))
    return F, Q, np.zeros(1), np.array([[1.0]]), meas


def test_a_jump_the_model_cannot_follow_is_taken_back_once_confirmed():
    F, Q, x0, P0, meas = _walk_problem()
    meas.z[6:, 0] += 20.0  # 20 sigma of the prediction: every later measurement agrees with it
    plain = forward_filter(F, Q, x0, P0, meas, gate_probability=0.9999)
    assert not plain.accepted[6:].any()  # the cascade: the plain gate never takes one again
    conf = confirmed_forward_filter(F, Q, x0, P0, meas, gate_probability=0.9999)
    assert conf.accepted.all()
    # the first of the run is taken back; its followers then pass the plain gate
    assert list(np.flatnonzero(conf.readmitted)) == [6]
    assert np.array_equal(conf.gate_accepted, plain.accepted)
    assert conf.nis[6] == pytest.approx(plain.nis[6])
    assert conf.x_post[-1, 0] == pytest.approx(20.0, abs=0.01)


def test_a_blunder_pair_stays_rejected_and_a_longer_run_needs_more_confirmation():
    F, Q, x0, P0, meas = _walk_problem()
    meas.z[[5, 6], 0] += 20.0  # two blunders that agree, the measurements after them right
    conf = confirmed_forward_filter(F, Q, x0, P0, meas, gate_probability=0.9999)
    assert list(np.flatnonzero(~conf.accepted)) == [5, 6] and not conf.readmitted.any()
    # three that agree with one another are taken with two confirming (and the right ones after
    # them cascade and are taken back in turn); with three confirming they are not
    meas.z[7, 0] += 20.0
    two = confirmed_forward_filter(F, Q, x0, P0, meas, gate_probability=0.9999)
    assert two.accepted.all() and list(np.flatnonzero(two.readmitted)) == [5, 8]
    three = confirmed_forward_filter(F, Q, x0, P0, meas, gate_probability=0.9999, confirming=3)
    assert list(np.flatnonzero(~three.accepted)) == [5, 6, 7]
    with pytest.raises(ValueError, match="at least 1"):
        confirmed_forward_filter(F, Q, x0, P0, meas, confirming=0)


def test_a_run_that_disagrees_with_itself_stays_rejected():
    F, Q, x0, P0, meas = _walk_problem()
    meas.z[5:, 0] += 20.0 * (-1.0) ** np.arange(7)  # +20, -20, +20, ...: no two agree
    conf = confirmed_forward_filter(F, Q, x0, P0, meas, gate_probability=0.9999)
    assert not conf.accepted[5:].any() and not conf.readmitted.any()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), blunders=st.lists(st.integers(0, 3), max_size=2, unique=True))
def test_confirmed_filter_is_the_plain_one_when_nothing_cascades(seed, blunders):
    F, Q, P0, meas = _level_problem(seed)
    meas.z[blunders] += 0.05  # 50 mm: rejected, and no run long enough to be tried
    plain = forward_filter(F, Q, np.zeros(5), P0, meas, gate_probability=0.9999)
    assert longest_run(~plain.accepted) <= CONFIRMING_MEASUREMENTS
    conf = confirmed_forward_filter(F, Q, np.zeros(5), P0, meas, gate_probability=0.9999)
    assert np.array_equal(conf.accepted, plain.accepted)
    assert np.array_equal(conf.x_post, plain.x_post) and np.array_equal(conf.P_post, plain.P_post)
    assert not conf.readmitted.any()
