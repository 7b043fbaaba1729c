"""Forward Kalman filter, RTS smoother and two-filter smoother on a node grid (Jiang 2017 Sec. 4.3).

The model is linear and time varying: between node ``k`` and ``k+1`` the state moves by
``x[k+1] = F[k] x[k] + w[k]``, ``w[k] ~ N(0, Q[k])``; at some nodes position fixes arrive,
``z = H x + v``, ``v ~ N(0, R)``. The forward filter is filterpy's ``KalmanFilter``; the RTS
smoother is filterpy's ``rts_smoother`` (Jiang 2017 Eq. 28). filterpy has no two-filter smoother,
so :func:`two_filter_smooth` is ours: a backward information filter, which starts from zero
information at the last node as Jiang 2017 requires (Eq. 34-35), combined with the forward
posterior by Eq. 27.

Fixes are gated by a chi-square test on the normalised innovation squared (NIS); a rejected fix
is kept in the result with its NIS, never silently dropped.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.stats


@dataclass
class Measurements:
    """Measurements at nodes, in node order (several at one node are applied in turn).

    Attributes
    ----------
    node : (M,) int index of the node each measurement belongs to.
    z : (M, m) measured values (innovation form: the dead-reckoning error seen by the fix).
    H : (M, m, n) or (m, n) measurement matrices.
    R : (M, m, m) or (m, m) measurement noise covariances.
    """

    node: np.ndarray
    z: np.ndarray
    H: np.ndarray
    R: np.ndarray

    def __post_init__(self) -> None:
        self.node = np.asarray(self.node, dtype=int)
        self.z = np.atleast_2d(np.asarray(self.z, dtype=float))
        M = self.node.shape[0]
        if self.z.shape[0] != M:
            self.z = self.z.reshape(M, -1)
        H = np.asarray(self.H, dtype=float)
        R = np.asarray(self.R, dtype=float)
        self.H = np.broadcast_to(H, (M,) + H.shape[-2:]).copy()
        self.R = np.broadcast_to(R, (M,) + R.shape[-2:]).copy()

    def __len__(self) -> int:
        return int(self.node.shape[0])

    def subset(self, mask: np.ndarray) -> "Measurements":
        """The measurements selected by a boolean mask."""
        return Measurements(self.node[mask], self.z[mask], self.H[mask], self.R[mask])


@dataclass
class ForwardResult:
    """Output of :func:`forward_filter`.

    Attributes
    ----------
    x_prior, P_prior : (K, n), (K, n, n) predicted state and covariance at each node.
    x_post, P_post : (K, n), (K, n, n) state and covariance after the node's measurements.
    innovation : (M, m) innovation of each measurement (z - H x before it).
    innovation_cov : (M, m, m) its covariance S.
    nis : (M,) normalised innovation squared y^T S^-1 y.
    accepted : (M,) bool, False where the gate rejected the measurement.
    """

    x_prior: np.ndarray
    P_prior: np.ndarray
    x_post: np.ndarray
    P_post: np.ndarray
    innovation: np.ndarray
    innovation_cov: np.ndarray
    nis: np.ndarray
    accepted: np.ndarray


@dataclass
class SmoothedResult:
    """Smoothed state and covariance at every node."""

    x: np.ndarray
    P: np.ndarray


#: Nodes between two calls of a progress callback (a few ms of filtering).
PROGRESS_EVERY = 500


def state_scale(P0: np.ndarray) -> np.ndarray:
    """The state scaling of :func:`rts_smooth` and :func:`two_filter_smooth`: the initial 1-sigmas,
    sqrt(diag P0), with 1 (no scaling) for a state known exactly at the start (a 0 or denormal
    variance, e.g. an odometer scale error of 0 in session.toml), which would otherwise divide by 0.
    """
    d = np.sqrt(np.abs(np.diag(np.asarray(P0, dtype=float))))
    return np.where(d > 1e-12, d, 1.0)


def gate_threshold(probability: float, dof: int) -> float:
    """Chi-square gate: NIS above this is rejected with false-alarm rate 1 - probability."""
    return float(scipy.stats.chi2.ppf(probability, dof))


def forward_filter(F: np.ndarray, Q: np.ndarray, x0: np.ndarray, P0: np.ndarray,
                   meas: Measurements, gate_probability: float | None = 0.9999,
                   force_accept: np.ndarray | None = None,
                   progress: Callable[[float], None] | None = None) -> ForwardResult:
    """Kalman filter over the node grid with filterpy's ``KalmanFilter``.

    Parameters
    ----------
    F, Q : (K-1, n, n) transition and process noise from node k to k+1.
    x0, P0 : prior state and covariance at node 0 (before its measurements).
    meas : measurements, sorted by node.
    gate_probability : chi-square gate probability (None: accept everything).
    force_accept : optional (M,) bool; True skips the gate for that measurement (the crew chose
        to accept a suspicious fix).
    progress : optional callable, given the fraction of nodes done (0..1) every
        ``PROGRESS_EVERY`` nodes.

    Returns
    -------
    ForwardResult
    """
    from filterpy.kalman import KalmanFilter  # about 1 s to import: only when filtering

    K = F.shape[0] + 1
    n = x0.shape[0]
    kf = KalmanFilter(dim_x=n, dim_z=meas.z.shape[1] if len(meas) else 1)
    kf.x = np.asarray(x0, dtype=float).reshape(n, 1).copy()
    kf.P = np.asarray(P0, dtype=float).copy()
    x_prior = np.empty((K, n))
    P_prior = np.empty((K, n, n))
    x_post = np.empty((K, n))
    P_post = np.empty((K, n, n))
    M = len(meas)
    innov = np.zeros((M, meas.z.shape[1] if M else 1))
    S_all = np.zeros((M,) + ((meas.z.shape[1],) * 2 if M else (1, 1)))
    nis = np.zeros(M)
    accepted = np.ones(M, dtype=bool)
    # index of the first measurement at or after each node (measurements are sorted by node)
    starts = np.searchsorted(meas.node, np.arange(K + 1)) if M else np.zeros(K + 1, dtype=int)
    threshold = gate_threshold(gate_probability, meas.z.shape[1]) if gate_probability is not None and M else np.inf
    for k in range(K):
        if progress is not None and k % PROGRESS_EVERY == 0:
            progress(k / K)
        if k > 0:
            # F and Q change every step: pass them to predict (filterpy keeps them otherwise)
            kf.predict(F=F[k - 1], Q=Q[k - 1])
        x_prior[k] = kf.x[:, 0]
        P_prior[k] = kf.P
        for j in range(starts[k], starts[k + 1]):
            H = meas.H[j]
            R = meas.R[j]
            z = meas.z[j].reshape(-1, 1)  # column vector: filterpy 2.0 reshapes x otherwise
            y = z - H @ kf.x
            S = H @ kf.P @ H.T + R
            innov[j] = y[:, 0]
            S_all[j] = S
            nis[j] = float(y[:, 0] @ np.linalg.solve(S, y[:, 0]))
            forced = force_accept is not None and bool(force_accept[j])
            if not forced and nis[j] > threshold:
                accepted[j] = False
                continue
            kf.update(z, R=R, H=H)
        x_post[k] = kf.x[:, 0]
        P_post[k] = kf.P
    if progress is not None:
        progress(1.0)
    return ForwardResult(x_prior, P_prior, x_post, P_post, innov, S_all, nis, accepted)


#: A measurement whose removal would change the smoothed estimate at its node by less than this
#: share of its own noise (the smallest eigenvalue of R^-1/2 (R - H P_s H^T) R^-1/2: the
#: redundancy of the measurement) is not tested: the others do not check it.
MIN_REDUNDANCY = 1e-3


def fix_statistics(meas: Measurements, accepted: np.ndarray, smoothed: SmoothedResult) -> np.ndarray:
    """Each measurement tested against the smoothed estimate from all the others (Baarda's data
    snooping, the leave-one-out form of the chi-square test).

    For a measurement the smoother used, the residual v = z - H x_s has covariance
    Q_v = R - H P_s H^T, and v^T Q_v^-1 v equals the NIS of z against the smoothed estimate of
    all the other measurements (leave-one-out identity: e = R Q_v^-1 v, S = R Q_v^-1 R). For
    one it did not use, the statistic is that NIS directly, with S = R + H P_s H^T. Both are
    chi-square with the measurement's dimension when the model holds, so one threshold serves
    (:func:`gate_threshold`). Unlike the forward gate, each measurement is judged by those before
    and after it.

    Parameters
    ----------
    meas : all the measurements.
    accepted : (M,) bool, those the smoother used.
    smoothed : the smoother's result from ``meas.subset(accepted)``.

    Returns
    -------
    (M,) statistics; NaN for a used measurement the others do not check (redundancy below
    :data:`MIN_REDUNDANCY`, e.g. the only one in reach).
    """
    accepted = np.asarray(accepted, dtype=bool)
    H, R = meas.H, meas.R
    v = meas.z - np.einsum("mij,mj->mi", H, smoothed.x[meas.node])
    HPH = H @ smoothed.P[meas.node] @ np.swapaxes(H, -1, -2)
    C = np.where(accepted[:, None, None], R - HPH, R + HPH)
    T = np.einsum("mi,mi->m", v, np.linalg.solve(C, v[:, :, None])[:, :, 0])
    if accepted.any():
        L = np.linalg.cholesky(R[accepted])
        Linv = np.linalg.inv(L)
        red = np.linalg.eigvalsh(Linv @ C[accepted] @ np.swapaxes(Linv, -1, -2))[:, 0]
        Ta = T[accepted]
        Ta[red < MIN_REDUNDANCY] = np.nan
        T[accepted] = Ta
    return T


@dataclass
class SnoopResult:
    """Output of :func:`snooped_verdicts`.

    Attributes
    ----------
    accepted : (M,) final verdicts.
    statistic : (M,) :func:`fix_statistics` with the final verdicts.
    removed : (M,) bool, accepted on entry and rejected by the snooping.
    added : (M,) bool, rejected on entry and taken back by it.
    moved_statistic : (M,) the statistic on which each measurement was last taken out or back
        (NaN for those never moved); a used one may be untestable at the end (NaN in
        ``statistic``) that was tested when it was taken.
    """

    accepted: np.ndarray
    statistic: np.ndarray
    removed: np.ndarray
    added: np.ndarray
    moved_statistic: np.ndarray


#: The test probability for taking out a measurement the forward gate took. All M are tested at
#: once, and the largest statistic is the one taken out: at the gate's 1e-4 per measurement, the
#: largest of 100 would exceed it about 1 % of the time, at 1e-6 (Bonferroni for 100) 1e-4, the
#: gate's own rate for one. Measured: one correct MEMS fix of 720 (36 simulated surveys) has a
#: statistic of 29.1, over the gate's 21.1 and under this 30.7; taking it out left a 43 mm
#: vertical error.
SNOOP_OUT_PROBABILITY = 1.0 - 1e-6


def snooped_verdicts(F: np.ndarray, Q: np.ndarray, x0: np.ndarray, P0: np.ndarray, meas: Measurements,
                     accepted: np.ndarray, gate_probability: float = 0.9999,
                     force_accept: np.ndarray | None = None, scale: np.ndarray | None = None,
                     smoothed: SmoothedResult | None = None,
                     out_probability: float = SNOOP_OUT_PROBABILITY) -> SnoopResult:
    """Data snooping on the smoothed estimate: the worst measurement out, the best back, in turn.

    Starting from the verdicts of a gate, the smoother is run on the accepted measurements and
    each measurement is tested against all the others (:func:`fix_statistics`). The used one
    with the largest statistic above the threshold is taken out; if none is, the unused one with
    the smallest statistic at or below it is taken back; if none is, a used one is taken out when
    without it an unused one passes (an exchange); then the smoother runs again. Each measurement
    moves at most once each way and is tried for an exchange once, so the loop ends (at most 3 M
    smoother runs; 104 forward runs, 2.4 s, for 101 MEMS fixes of which every other is 30 mm off).
    A forward gate judges a fix by
    the ones before it only: after it took a wrong fix, or before a correct one it rejected, it
    cannot tell the fixes after from wrong ones. Baarda's data snooping (one outlier at a time,
    the largest first) is what surveyors apply to a network adjustment; filterpy has no smoother
    test of this kind, hence this function. A measurement is taken back at the gate's threshold
    and taken out at the stricter ``out_probability`` (:data:`SNOOP_OUT_PROBABILITY`).

    Parameters
    ----------
    F, Q, x0, P0, meas : as for :func:`forward_filter` (all measurements).
    accepted : (M,) bool, the verdicts to start from.
    gate_probability : chi-square probability of the test for taking a measurement back.
    force_accept : optional (M,) bool, never taken out (the crew accepted them).
    scale : state scaling for :func:`rts_smooth`.
    smoothed : optional, the smoother's result for ``accepted`` (saves its first run).
    out_probability : chi-square probability of the test for taking a measurement out.

    Returns
    -------
    SnoopResult
    """
    M = len(meas)
    acc = np.asarray(accepted, dtype=bool).copy()
    forced = np.zeros(M, dtype=bool) if force_accept is None else np.asarray(force_accept, dtype=bool)
    moved_out = np.zeros(M, dtype=bool)
    moved_in = np.zeros(M, dtype=bool)
    exchange_tried = np.zeros(M, dtype=bool)
    moved_T = np.full(M, np.nan)
    start = acc.copy()
    threshold = gate_threshold(gate_probability, meas.z.shape[1])
    out_threshold = gate_threshold(out_probability, meas.z.shape[1])

    def smoothed_for(mask: np.ndarray) -> SmoothedResult:
        return rts_smooth(F, Q, forward_filter(F, Q, x0, P0, meas.subset(mask), gate_probability=None),
                          scale=scale)

    sm = smoothed if smoothed is not None else smoothed_for(acc)
    while True:
        T = fix_statistics(meas, acc, sm)
        testable = acc & ~forced & ~moved_out & np.isfinite(T)
        out = testable & (T > out_threshold)
        back = ~acc & ~moved_in & (T <= threshold)
        if out.any() or back.any():
            # the worst used fix out first; else the best rejected one back
            use = not out.any()
            j = (int(np.flatnonzero(back)[np.argmin(T[back])]) if use
                 else int(np.flatnonzero(out)[np.argmax(T[out])]))
            acc[j] = use
            (moved_in if use else moved_out)[j] = True
            moved_T[j] = T[j]
            sm = smoothed_for(acc)
            continue
        # Exchanges: a used fix is taken out if a rejected one comes back without it. A wrong fix
        # the forward gate took after rejecting the first ones of a bad setup holds the track
        # against every right fix after it (RLG, three fixes 50 mm off: its statistic 22, the
        # right ones' 35-627; 36 mm off: 17, under the gate); a right one of an overconfident
        # model (MEMS, 29.1) lets none back and stays. Tried in order: over the gate or
        # untestable first, then by the statistic, largest first; each once. (Requiring two to
        # come back for one that passes was no better: 47 of 48 random runs of wrong RLG fixes
        # found either way, FOG 21 of 24 with one more wrong fix used.)
        candidates = acc & ~forced & ~moved_out & ~exchange_tried
        if acc.all() or not candidates.any():
            return SnoopResult(acc, T, start & ~acc, ~start & acc, moved_T)
        suspect = ~(T <= threshold)
        order = np.lexsort((-np.nan_to_num(T, nan=np.inf), ~suspect))
        j = int(order[candidates[order]][0])
        exchange_tried[j] = True
        trial = acc.copy()
        trial[j] = False
        sm_trial = smoothed_for(trial)
        back_without = ~trial & ~moved_in & (fix_statistics(meas, trial, sm_trial) <= threshold)
        back_without[j] = False
        if back_without.any():
            acc = trial
            moved_out[j] = True
            moved_in[j] = True  # not back: it may still pass alone, beside the ones it held out
            moved_T[j] = T[j]
            sm = sm_trial


def rts_smooth(F: np.ndarray, Q: np.ndarray, fwd: ForwardResult,
               scale: np.ndarray | None = None,
               progress: Callable[[float], None] | None = None) -> SmoothedResult:
    """Rauch-Tung-Striebel smoother (Jiang 2017 Eq. 28) with filterpy's ``rts_smoother``.

    filterpy's procedural ``rts_smoother(Xs, Ps, Fs, Qs)`` uses ``Fs[k]`` as the transition from
    node k to k+1, which is our convention; the last entry is unused.

    Parameters
    ----------
    F, Q : (K-1, n, n) model.
    fwd : forward filter result.
    scale : optional (n,) state scaling, as in :func:`two_filter_smooth`. The RTS gain inverts the
        predicted covariance; with states from 1e-3 m to 1e-7 rad/s unscaled, that inverse loses
        up to six digits of the smoothed covariance (checked against 40-digit arithmetic in
        ``tests/test_smoothers.py``); scaled, it keeps eleven.
    progress : optional callable, given the fraction done (filterpy's pass counts as half).
    """
    from filterpy.kalman import rts_smoother

    K, n = fwd.x_post.shape
    d = np.ones(n) if scale is None else np.asarray(scale, dtype=float)
    Dinv = 1.0 / d
    Fs = np.concatenate([F * Dinv[None, :, None] * d[None, None, :], np.eye(n)[None]], axis=0)
    Qs = np.concatenate([Q * Dinv[None, :, None] * Dinv[None, None, :], np.zeros((1, n, n))], axis=0)
    Pf = fwd.P_post * Dinv[None, :, None] * Dinv[None, None, :]
    x, _, C, _ = rts_smoother(fwd.x_post * Dinv[None, :], Pf, Fs, Qs)
    if progress is not None:
        progress(0.5)
    # filterpy updates the covariance as P_f + C (P_s' - P_pred) C^T: a difference of nearly
    # equal matrices when a fix shrinks the covariance by orders of magnitude (it lost up to six
    # digits against 40-digit arithmetic). With filterpy's gains C, the algebraically equal
    # Joseph-type form (I - C F) P_f (I - C F)^T + C (Q + P_s') C^T adds only positive terms.
    # The terms that do not depend on P_s[k+1] are batched; the recursion itself is sequential.
    C = C[:-1]
    IKF = np.eye(n) - C @ Fs[:-1]
    Ct = np.swapaxes(C, -1, -2)
    A = IKF @ Pf[:-1] @ np.swapaxes(IKF, -1, -2) + C @ Qs[:-1] @ Ct
    P = np.empty_like(Pf)
    P[-1] = Pf[-1]
    for k in range(K - 2, -1, -1):
        if progress is not None and k % PROGRESS_EVERY == 0:
            progress(1.0 - 0.5 * k / K)
        P[k] = A[k] + C[k] @ P[k + 1] @ Ct[k]
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    return SmoothedResult(x * d[None, :], P * d[None, :, None] * d[None, None, :])


def two_filter_smooth(F: np.ndarray, Q: np.ndarray, meas: Measurements,
                      fwd: ForwardResult, scale: np.ndarray | None = None,
                      progress: Callable[[float], None] | None = None) -> SmoothedResult:
    """Two-filter smoother (Jiang 2017 Eq. 27): forward posterior fused with a backward filter.

    The backward filter runs in information form (Y, y) from the last node, where it starts with
    zero information (Jiang 2017 Eq. 35: P_b^-1(T) = 0 before the last fix). Its prediction from
    node k+1 to k uses ``(Y^-1 + Q)^-1 = (I + Y Q)^-1 Y``, valid for singular Y, so neither F nor
    Y is inverted. filterpy has no two-filter smoother, hence this implementation.

    Parameters
    ----------
    F, Q : (K-1, n, n) model, as for :func:`forward_filter`.
    meas : the measurements the forward filter accepted (use ``meas.subset(fwd.accepted)``).
    fwd : forward filter result.
    scale : optional (n,) state scaling (e.g. the square root of diag P0). The algebra is done on
        ``x / scale`` so that states of very different sizes (mm and 1e-7 rad/s) do not ruin the
        conditioning of the information matrices; the result is scaled back.
    progress : optional callable, given the fraction of nodes done (0..1).

    Returns
    -------
    SmoothedResult
    """
    K, n = fwd.x_post.shape
    d = np.ones(n) if scale is None else np.asarray(scale, dtype=float)
    Dinv = 1.0 / d
    # scaled model: x' = D^-1 x
    Fs = F * Dinv[None, :, None] * d[None, None, :]
    Qs = Q * Dinv[None, :, None] * Dinv[None, None, :]
    Hs = meas.H * d[None, None, :]
    Rinv = np.linalg.inv(meas.R)
    HtRinvH = np.swapaxes(Hs, -1, -2) @ Rinv @ Hs
    HtRinvz = (np.swapaxes(Hs, -1, -2) @ Rinv @ meas.z[:, :, None])[:, :, 0]
    # information of all measurements at each node, summed
    node_Y = np.zeros((K, n, n))
    node_y = np.zeros((K, n))
    np.add.at(node_Y, meas.node, HtRinvH)
    np.add.at(node_y, meas.node, HtRinvz)

    Yb = np.zeros((K, n, n))  # backward information at node k from nodes > k (the "prior")
    yb = np.zeros((K, n))
    Y = node_Y[K - 1].copy()
    y = node_y[K - 1].copy()
    eye = np.eye(n)
    for k in range(K - 2, -1, -1):
        if progress is not None and k % PROGRESS_EVERY == 0:
            progress(1.0 - k / K)
        B = np.linalg.solve(eye + Y @ Qs[k], np.column_stack([Y, y]))  # (I + Y Q)^-1 [Y, y]
        M_ = B[:, :n]
        Yb[k] = Fs[k].T @ M_ @ Fs[k]
        yb[k] = Fs[k].T @ B[:, n]
        Y = Yb[k] + node_Y[k]
        y = yb[k] + node_y[k]

    Pf = fwd.P_post * Dinv[None, :, None] * Dinv[None, None, :]
    xf = fwd.x_post * Dinv[None, :]
    Pf_inv = np.linalg.inv(Pf)
    info = Pf_inv + Yb
    Ps = np.linalg.inv(info)
    Ps = 0.5 * (Ps + np.swapaxes(Ps, -1, -2))
    xs = (Ps @ ((Pf_inv @ xf[:, :, None])[:, :, 0] + yb)[:, :, None])[:, :, 0]
    return SmoothedResult(xs * d[None, :], Ps * d[None, :, None] * d[None, None, :])
