"""Forward filter, RTS (filterpy) and two-filter smoother agree; gating keeps rejected fixes."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from trolley import error_models as em
from trolley.smoothers import (Measurements, fix_statistics, forward_filter, gate_threshold, rts_smooth,
                               snooped_verdicts, two_filter_smooth)


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


def _snooped(F, Q, x0, P0, meas, **kw):
    gated = forward_filter(F, Q, x0, P0, meas, gate_probability=0.9999)
    return gated, snooped_verdicts(F, Q, x0, P0, meas, gated.accepted, 0.9999, **kw)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), j=st.integers(0, 3))
def test_fix_statistic_is_the_nis_against_a_smoother_run_without_the_fix(seed, j):
    # the leave-one-out identity against its definition: smooth without fix j, then its NIS
    F, Q, P0, meas = _level_problem(seed)
    acc = np.ones(len(meas), dtype=bool)
    sm = rts_smooth(F, Q, forward_filter(F, Q, np.zeros(5), P0, meas, gate_probability=None))
    T = fix_statistics(meas, acc, sm)
    acc[j] = False
    sm_without = rts_smooth(F, Q, forward_filter(F, Q, np.zeros(5), P0, meas.subset(acc), gate_probability=None))
    k = meas.node[j]
    e = meas.z[j] - meas.H[j] @ sm_without.x[k]
    S = meas.H[j] @ sm_without.P[k] @ meas.H[j].T + meas.R[j]
    assert T[j] == pytest.approx(float(e @ np.linalg.solve(S, e)), rel=1e-6, abs=1e-9)
    # and for an unused fix the statistic is that NIS directly
    assert fix_statistics(meas, acc, sm_without)[j] == pytest.approx(T[j], rel=1e-6, abs=1e-9)


def test_a_measurement_no_other_checks_is_not_tested():
    F, Q, x0, _, meas = _walk_problem(n_meas=3)
    P0 = np.array([[1e4]])  # the prior does not check the first one either
    acc = np.array([True, False, False])
    sm = rts_smooth(F, Q, forward_filter(F, Q, x0, P0, meas.subset(acc), gate_probability=None))
    T = fix_statistics(meas, acc, sm)
    assert np.isnan(T[0]) and np.isfinite(T[1:]).all()


def _drift_problem(n_meas: int = 16, qv: float = 0.05, sigma: float = 0.01):
    """Position and drift rate (constant velocity, rate random walk qv per step), position
    measured every step: as the dead reckoning drifts with a heading error, one accepted wrong
    fix turns the predicted drift, and one rejected right one leaves it unchecked."""
    F = np.tile(np.array([[1.0, 1.0], [0.0, 1.0]]), (n_meas - 1, 1, 1))
    Q = np.tile(np.diag([0.0, qv**2]), (n_meas - 1, 1, 1))
    meas = Measurements(np.arange(n_meas), np.zeros((n_meas, 1)), np.array([[1.0, 0.0]]), np.full((1, 1), sigma**2))
    return F, Q, np.zeros(2), np.eye(2), meas


def test_right_fixes_the_forward_gate_rejected_in_a_row_are_taken_back():
    F, Q, x0, P0, meas = _drift_problem()
    k = np.arange(len(meas))
    meas.z[:, 0] = np.where(k >= 6, 0.30 * (k - 5), 0.0)  # the drift turns by 6 of its sigmas at 5
    gated, res = _snooped(F, Q, x0, P0, meas)
    assert list(np.flatnonzero(~gated.accepted)) == [6, 7, 8, 9, 10]  # the forward gate's cascade
    assert res.accepted.all() and list(np.flatnonzero(res.added)) == [6, 7, 8, 9, 10]
    # the fix at the turn stays over the gate (18.5 > 15.1), under the threshold for taking out
    assert np.max(res.statistic) == pytest.approx(18.54, abs=0.01)
    assert (res.statistic <= gate_threshold(1 - 1e-6, 1)).all()


@pytest.mark.parametrize("run", [[5], [5, 6], [5, 6, 7], [5, 6, 7, 8]])
def test_wrong_measurements_that_agree_with_one_another_stay_rejected(run):
    F, Q, x0, P0, meas = _walk_problem(n_meas=16)
    meas.z[run, 0] += 20.0  # one bad setup measuring several stops, the rest right
    gated, res = _snooped(F, Q, x0, P0, meas)
    assert list(np.flatnonzero(~res.accepted)) == run


def test_a_wrong_measurement_the_gate_took_is_exchanged_for_the_right_ones_it_held_out():
    # the prior sigma grows while the gate rejects: the third wrong fix of a run passes the
    # forward gate, turns the drift, and the right ones after it fail
    F, Q, x0, P0, meas = _drift_problem()
    meas.z[[5, 6, 7], 0] += 0.5
    gated, res = _snooped(F, Q, x0, P0, meas)
    assert list(np.flatnonzero(~gated.accepted)) == [5, 6, 8, 9, 10, 11]
    assert list(np.flatnonzero(~res.accepted)) == [5, 6, 7]
    assert list(np.flatnonzero(res.removed)) == [7] and list(np.flatnonzero(res.added)) == [8, 9, 10, 11]


def test_a_wrong_fix_that_passes_is_exchanged_when_right_ones_come_back_without_it():
    # smaller wrong fixes on a stiffer drift: the third passes against the others (12.5 < 15.1),
    # and holds every right fix after it out; without it all eight come back
    F, Q, x0, P0, meas = _drift_problem(qv=0.02)
    meas.z[[5, 6, 7], 0] += 0.3
    gated, res = _snooped(F, Q, x0, P0, meas)
    assert list(np.flatnonzero(~gated.accepted)) == [5, 6] + list(range(8, 16))
    assert list(np.flatnonzero(~res.accepted)) == [5, 6, 7]


def test_a_right_fix_is_not_traded_for_a_lone_wrong_one():
    F, Q, x0, P0, meas = _drift_problem()
    meas.z[6, 0] += 0.5  # alone: the right ones beside it hold it out, and are not traded for it
    gated, res = _snooped(F, Q, x0, P0, meas)
    assert list(np.flatnonzero(~gated.accepted)) == [6]
    assert list(np.flatnonzero(~res.accepted)) == [6]


def test_the_crew_keeps_a_fix_the_snooping_would_take_out():
    F, Q, x0, P0, meas = _drift_problem()
    meas.z[[5, 6, 7], 0] += 0.5
    forced = np.zeros(len(meas), dtype=bool)
    forced[7] = True
    gated = forward_filter(F, Q, x0, P0, meas, gate_probability=0.9999, force_accept=forced)
    res = snooped_verdicts(F, Q, x0, P0, meas, gated.accepted, 0.9999, force_accept=forced)
    assert res.accepted[7]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_snooping_changes_nothing_on_consistent_data(seed):
    F, Q, P0, meas = _level_problem(seed)
    gated = forward_filter(F, Q, np.zeros(5), P0, meas, gate_probability=0.9999)
    res = snooped_verdicts(F, Q, np.zeros(5), P0, meas, gated.accepted, 0.9999)
    if gated.accepted.all() and np.nanmax(res.statistic) <= gate_threshold(0.9999, 2):
        assert res.accepted.all() and not res.removed.any() and not res.added.any()
    # whatever it changed, every used measurement it could test ends under the out threshold and
    # every unused one over the gate
    T = res.statistic
    assert not (res.accepted & (T > gate_threshold(1 - 1e-6, 2))).any()
    assert (T[~res.accepted] > gate_threshold(0.9999, 2)).all()
