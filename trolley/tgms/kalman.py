"""Linear time-varying Kalman filter with RTS smoothing, shared by the TGMS estimators.

The forward pass is a plain loop over the (decimated) processing samples that also accumulates
the Gaussian log-likelihood of the innovations (what the constrained maximum-likelihood tuning of
Gonzalez-Carbajal 2023 Sec. 4.2 maximises); the backward pass is our own Rauch-Tung-Striebel
smoother (:func:`rts`), not ``filterpy.kalman.rts_smoother``: filterpy's predicts with F x only,
without the known input term B u that every model here has (gyro and accelerometer inputs), and
takes one constant Q, while ours are time-varying.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FilterResult:
    """Forward filter and smoother output.

    Attributes
    ----------
    x_f, P_f : filtered states (n, k) and covariances (n, k, k).
    x_s, P_s : smoothed states and covariances (None if not smoothed).
    loglik : log-likelihood of the innovations.
    """

    x_f: np.ndarray
    P_f: np.ndarray
    x_s: np.ndarray | None
    P_s: np.ndarray | None
    loglik: float


def ltv_filter(x0: np.ndarray, P0: np.ndarray, F: np.ndarray, Bu: np.ndarray, Q: np.ndarray,
               H: np.ndarray, R: np.ndarray, z: np.ndarray, smooth: bool = True) -> FilterResult:
    """Kalman filter for x_{k+1} = F_k x_k + Bu_k + q_k, z_k = H_k x_k + r_k, then RTS smoothing.

    Parameters
    ----------
    x0, P0 : prior of the first state.
    F : (n, k, k) transition from step k to k+1 (the last one unused) or (k, k) constant.
    Bu : (n, k) known input term.
    Q : (n, k, k) or (k, k) process noise.
    H : (n, m, k) or (m, k) measurement matrix.
    R : (n, m, m) or (m, m) measurement noise.
    z : (n, m) measurements; NaN rows (or NaN entries) are skipped.
    smooth : run the RTS smoother.

    Returns
    -------
    FilterResult

    References
    ----------
    Gonzalez-Carbajal 2023 Eq. 13 (state-space model), Sec. 4.2 (log-likelihood).
    """
    n, m = z.shape
    k = len(x0)
    Fs = np.broadcast_to(F, (n, k, k)) if F.ndim == 2 else F
    Qs = np.broadcast_to(Q, (n, k, k)) if Q.ndim == 2 else Q
    Hs = np.broadcast_to(H, (n, m, k)) if H.ndim == 2 else H
    Rs = np.broadcast_to(R, (n, m, m)) if R.ndim == 2 else R
    xf = np.empty((n, k))
    Pf = np.empty((n, k, k))
    x = np.asarray(x0, float).copy()
    P = np.asarray(P0, float).copy()
    ll = 0.0
    I = np.eye(k)
    for i in range(n):
        if i > 0:
            Fi = Fs[i - 1]
            x = Fi @ x + Bu[i - 1]
            P = Fi @ P @ Fi.T + Qs[i - 1]
        zi = z[i]
        use = np.isfinite(zi)
        if use.any():
            Hi = Hs[i][use]
            Ri = Rs[i][np.ix_(use, use)]
            y = zi[use] - Hi @ x
            PHt = P @ Hi.T
            S = Hi @ PHt + Ri
            Si = np.linalg.inv(S)
            K = PHt @ Si
            x = x + K @ y
            IKH = I - K @ Hi
            P = IKH @ P @ IKH.T + K @ Ri @ K.T
            sign, logdet = np.linalg.slogdet(S)
            ll -= 0.5 * (y @ Si @ y + logdet + len(y) * np.log(2 * np.pi))
        xf[i] = x
        Pf[i] = P
    xs = Ps = None
    if smooth:
        xs, Ps = rts(xf, Pf, Fs, Bu, Qs)
    return FilterResult(xf, Pf, xs, Ps, float(ll))


def rts(xf: np.ndarray, Pf: np.ndarray, F: np.ndarray, Bu: np.ndarray, Q: np.ndarray):
    """Rauch-Tung-Striebel smoother for a model with a known input term.

    ``filterpy.kalman.rts_smoother`` predicts with F x only (no input), which is wrong for these
    input-driven models (gyro and accelerometer inputs), hence this loop with the same algebra plus
    Bu.

    Returns
    -------
    xs (n, k), Ps (n, k, k)
    """
    n = len(xf)
    xs = xf.copy()
    Ps = Pf.copy()
    for i in range(n - 2, -1, -1):
        Fi = F[i]
        Pp = Fi @ Pf[i] @ Fi.T + Q[i]
        C = Pf[i] @ Fi.T @ np.linalg.inv(Pp)
        xs[i] = xf[i] + C @ (xs[i + 1] - (Fi @ xf[i] + Bu[i]))
        Ps[i] = Pf[i] + C @ (Ps[i + 1] - Pp) @ C.T
    return xs, Ps
