"""Kalman filter (and RTS smoother) for the lateral alignment from wheelset and frame sensors.

Implements Munoz et al. 2021, Sec. IV: the state x = [y, psi, y_f, y', psi', y_f', xi] (Eq. 7) of
the simplified model (:mod:`trolley.inservice.model`), the measurements z = [y''_meas, psi'_meas,
y_f''_meas, xi_meas = 0] (Eq. 8; the last one a virtual sensor that keeps xi from drifting), the
discrete model x_k = F x_(k-1) + v_k, z_k = H x_k + w_k (Eq. 16-17), the filter Eq. 18-24 and the
observability test Eq. 25.

Differences from the paper
--------------------------
* Discretisation: F = expm(Fc dt) (exact for the linear model) instead of the paper's modified Euler
  step; the input matrix of the design curvature and, when Q is given as continuous spectral
  densities, Q itself by Van Loan's method (one expm of the block matrix [[-Fc, Qc], [0, Fc^T]] dt).
* An RTS smoother (filterpy.kalman.rts_smoother) after the forward filter: the alignment at each
  point then uses the sensors after it as well (the paper filters only).
* Variable speed: F and Q are rebuilt per speed bin of :data:`SPEED_BIN_M_S` (the SM depends on V
  through the creep damping).
* Curved track: the design curvature kappa is a known input (model.py); the RTS smoother runs on
  the deviation from the deterministic curvature response so that filterpy's input-free smoother
  stays exact.

The per-sample loop is filterpy's predict/update (the filter is sequential); everything else is
vectorised. filterpy 2.0 reshapes z only when H is None, so measurements are passed as (4, 1)
column vectors (shared/research/deps.md section 2).

References
----------
Munoz, Ros, Urda, Escalona, IEEE Access 9 (2021), Eq. 7-8, 11-25.
C. F. Van Loan, "Computing integrals involving the matrix exponential", IEEE TAC 23 (1978).
H. E. Rauch, F. Tung, C. T. Striebel, AIAA J. 3 (1965) (RTS smoother).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from trolley.inservice.model import N_MEAS, STATE_KINDS, XI_INDEX, DesignParameters

#: speeds are grouped into bins of this width (m/s) for the speed-dependent F, Q
SPEED_BIN_M_S = 0.1
#: chainage at a record's start that every statistic of an estimate leaves out (the filter's
#: start-up from its wide P0): honesty, sigma scale, innovations, m
SETTLE_M = 30.0


def discretize(Fc: np.ndarray, Bc: np.ndarray, dt: float, Qc: np.ndarray | None = None):
    """Zero-order-hold discretisation of x' = Fc x + Bc u + v, v ~ N(0, Qc) (Eq. 16).

    Parameters
    ----------
    Fc : (n, n) continuous state matrix.
    Bc : (n, m) input matrix.
    dt : sample interval, s.
    Qc : (n, n) spectral density of the continuous process noise, or None.

    Returns
    -------
    F : (n, n) expm(Fc dt).
    G : (n, m) integral_0^dt expm(Fc s) ds Bc.
    Qd : (n, n) integral_0^dt expm(Fc s) Qc expm(Fc s)^T ds (Van Loan), or None.
    """
    from scipy.linalg import expm

    n, m = Bc.shape
    blk = np.zeros((n + m, n + m))
    blk[:n, :n] = Fc
    blk[:n, n:] = Bc
    E = expm(blk * dt)
    F, G = E[:n, :n], E[:n, n:]
    if Qc is None:
        return F, G, None
    vl = np.zeros((2 * n, 2 * n))
    vl[:n, :n] = -Fc
    vl[:n, n:] = Qc
    vl[n:, n:] = Fc.T
    V = expm(vl * dt)
    Qd = F @ V[:n, n:]
    return F, G, 0.5 * (Qd + Qd.T)


@dataclass(frozen=True)
class NoiseDensities:
    """Continuous process-noise densities and measurement sigmas for a default (Q, R).

    Attributes
    ----------
    force_m2_s3 : spectral density of the unmodelled accelerations of y, y_f (m^2/s^3).
    yaw_rad2_s3 : spectral density of the unmodelled yaw acceleration (rad^2/s^3).
    xi_m2_per_m : spectral density of the alignment's random walk per metre of track (m^2/m);
        the time density is this times the speed.
    sigma_acc_m_s2, sigma_gyro_rad_s : sensor noise (Munoz 2021 Sec. V: 0.01 m/s^2, 5e-4 rad/s).
    sigma_xi_virtual_m : sigma of the virtual measurement xi = 0 (paper: 5 mm).
    roll_rad2_per_m : spectral density of the cross-level roll's random walk per metre of track
        (rad^2/m), for models whose accelerometers sense gravity (model.with_sensor_gravity): the
        Eq. 27 estimate of a calibration on the benchmark's track (5e-9 rad^2 per 5 ms step at
        20 m/s).
    """

    force_m2_s3: float = 2.0e-3
    yaw_rad2_s3: float = 2.0e-4
    xi_m2_per_m: float = 2.0e-8
    sigma_acc_m_s2: float = 0.01
    sigma_gyro_rad_s: float = 5.0e-4
    sigma_xi_virtual_m: float = 5.0e-3
    roll_rad2_per_m: float = 5.0e-8

    def qc(self, speed_m_s: float, state_kinds=STATE_KINDS) -> np.ndarray:
        """Continuous Qc at a given speed for states of the given kinds
        (DesignParameters.state_kinds): the densities drive the velocities and xi."""
        per_kind = {"vy": self.force_m2_s3, "wz": self.yaw_rad2_s3, "xi": self.xi_m2_per_m * speed_m_s,
                    "roll": self.roll_rad2_per_m * speed_m_s}
        return np.diag([per_kind.get(k, 0.0) for k in state_kinds])

    def r(self) -> np.ndarray:
        """Measurement covariance R (4x4, Eq. 17)."""
        return np.diag([self.sigma_acc_m_s2, self.sigma_gyro_rad_s, self.sigma_acc_m_s2,
                        self.sigma_xi_virtual_m]) ** 2


@dataclass(frozen=True)
class DiscreteModel:
    """The discrete SM at one speed and sample interval (Eq. 16-17)."""

    F: np.ndarray
    G: np.ndarray
    H: np.ndarray
    D: np.ndarray
    Q: np.ndarray


def discrete_model(p: DesignParameters, speed_m_s: float, dt: float, Q=None,
                   noise: NoiseDensities | None = None) -> DiscreteModel:
    """F, G (curvature input), H, D and Q of a design model at one speed.

    Parameters
    ----------
    p : design model parameters (model.ModelParameters, the paper's SM, or bogie.BogieParameters).
    speed_m_s : forward speed, m/s.
    dt : sample interval, s.
    Q : (n, n) discrete process covariance per step (e.g. from Eq. 26-27), or None to build it
        from ``noise`` by Van Loan.
    noise : continuous densities used when Q is None (default NoiseDensities()).

    Returns
    -------
    DiscreteModel
    """
    Fc, Bc, Hc, Dc = p.state_space(speed_m_s)
    if Q is None:
        F, G, Qd = discretize(Fc, Bc, dt, (noise or NoiseDensities()).qc(speed_m_s, p.state_kinds))
    else:
        F, G, _ = discretize(Fc, Bc, dt)
        Qd = np.asarray(Q, float)
    return DiscreteModel(F, G, Hc, Dc, Qd)


def observability_matrix(F: np.ndarray, H: np.ndarray) -> np.ndarray:
    """O = [H; H F; ...; H F^(n-1)] (Munoz 2021 Eq. 25)."""
    n = F.shape[0]
    blocks, M = [], H.copy()
    for _ in range(n):
        blocks.append(M)
        M = M @ F
    return np.vstack(blocks)


def observability_rank(F: np.ndarray, H: np.ndarray) -> int:
    """Rank of the observability matrix (numpy.linalg.matrix_rank with scaled columns).

    The columns are scaled to unit norm first: the states mix metres, radians and their rates.
    """
    O = observability_matrix(F, H)
    O = O / np.maximum(np.linalg.norm(O, axis=0), 1e-300)
    return int(np.linalg.matrix_rank(O))


@dataclass
class AlignmentEstimate:
    """Result of :func:`estimate`: states, their sigmas and the alignment with its sigma.

    Attributes
    ----------
    t_s, s_m : sample times (s) and chainages (m).
    x : (N, n) state estimates (smoothed when the smoother ran, else filtered); n = 7 for the
        paper's model (Eq. 7), 20 for the bogie model, the alignment at index 6 in both.
    sigma : (N, n) square roots of the diagonal of the state covariance.
    x_filtered : (N, n) forward-filter estimates.
    smoother : "rts" or "none".
    transitions : (N, n, n) how the estimation errors of neighbouring samples are linked, for
        :func:`band_alignment`: with the smoother its gains C_k (e_k = C_k e_(k+1) + a part
        independent of the later errors; the last one unused), else the filter's error transition
        A_k = (I - K_k H) F_k (e_k = A_k e_(k-1) + a part independent of the earlier errors).
    cov_xi : (N, n) column of the state covariance belonging to xi, P_k[:, 6].
    normalized_innovations : (N, 4) the forward filter's innovations divided by their predicted
        sigmas sqrt(diag(H P H^T + R)), per channel [wheelset acc, gyro, frame acc, virtual xi]
        (:func:`innovation_rms`).
    """

    t_s: np.ndarray
    s_m: np.ndarray
    x: np.ndarray
    sigma: np.ndarray
    x_filtered: np.ndarray
    smoother: str
    transitions: np.ndarray | None = None
    cov_xi: np.ndarray | None = None
    normalized_innovations: np.ndarray | None = None

    @property
    def alignment_m(self) -> np.ndarray:
        """Estimated alignment xi, m."""
        return self.x[:, XI_INDEX]

    @property
    def sigma_alignment_m(self) -> np.ndarray:
        """1-sigma of the estimated alignment, m."""
        return self.sigma[:, XI_INDEX]


def _rts_from_priors(Xf, Pf, Xp, Pp, Fs):
    """Rauch-Tung-Striebel backward pass from the forward filter's posteriors and priors.

    filterpy's rts_smoother recomputes the priors as F x without an input term; with the
    measurement-dependent input of the correlated-noise form (``estimate(..., S=...)``) the
    stored priors x_(k+1|k), P_(k+1|k) are used instead (the same recursion, Rauch et al. 1965):
    C_k = P_k F_(k+1)^T P_(k+1|k)^-1, x_k^s = x_k + C_k (x_(k+1)^s - x_(k+1|k)),
    P_k^s = P_k + C_k (P_(k+1)^s - P_(k+1|k)) C_k^T. The gains are computed for all k at once.
    """
    n = len(Xf)
    F = np.stack(Fs)
    # C_k^T = solve(P_(k+1|k), F_(k+1) P_k) (P symmetric), batched over k
    C = np.swapaxes(np.linalg.solve(Pp[1:], F[1:] @ Pf[:-1]), 1, 2)
    Xs, Ps = Xf.copy(), Pf.copy()
    for k in range(n - 2, -1, -1):
        Xs[k] = Xf[k] + C[k] @ (Xs[k + 1] - Xp[k + 1])
        Ps[k] = Pf[k] + C[k] @ (Ps[k + 1] - Pp[k + 1]) @ C[k].T
    return Xs, Ps, np.concatenate([C, np.zeros((1,) + C.shape[1:])])


#: default initial sigmas per kind of state (Eq. 19): 5 mm, 2 mrad and their rates of a few cm/s; the
#: cross-level roll 3 mrad (4.3 mm of cross level)
INITIAL_SIGMA = {"y": 5e-3, "psi": 2e-3, "vy": 5e-2, "wz": 2e-2, "xi": 5e-3, "delay": 5e-3, "roll": 3e-3}


def _initial_covariance(state_kinds=STATE_KINDS) -> np.ndarray:
    return np.diag([INITIAL_SIGMA[k] for k in state_kinds]) ** 2


def estimate(p: DesignParameters, t_s, s_m, speed_m_s, measurements, R=None, Q=None,
             noise: NoiseDensities | None = None, curvature_1_m=None,
             smoother: str = "rts", initial_covariance=None, S=None) -> AlignmentEstimate:
    """Estimate the lateral alignment along a run (Munoz 2021 Sec. IV, plus an RTS smoother).

    Parameters
    ----------
    p : design model parameters, the SM (model.ModelParameters) or the bogie model
        (bogie.BogieParameters); nominal, or with p_opt identified by identification.py.
    t_s : (N,) sample times, s (uniform).
    s_m : (N,) chainage of the instrumented wheelset, m.
    speed_m_s : (N,) or scalar forward speed, m/s.
    measurements : (N, 3) [wheelset lateral acc (m/s^2), wheelset yaw rate (rad/s), frame lateral
        acc (m/s^2)]; the virtual xi = 0 is appended here (Eq. 8).
    R : (4, 4) measurement covariance (Eq. 29), default ``noise.r()``.
    Q : (n, n) discrete process covariance per step (Eq. 27), default from ``noise`` (Van Loan).
    noise : continuous densities and sensor sigmas for the defaults.
    curvature_1_m : (N,) or scalar design curvature (1/m, positive to the left) or None.
    smoother : "rts" (filterpy.kalman.rts_smoother) or "none" (forward filter only, as the paper).
    initial_covariance : (n, n) P0 (Eq. 19) around x0 = 0 (Eq. 18); default: 5 mm, 2 mrad and their
        rates of a few cm/s.
    S : (n, 4) cross covariance E[v_k w_(k-1)^T] of the process noise of step k and the measurement
        error of the sample before it (identification.covariances_from_residuals), or None
        (uncorrelated, the paper). Given S, the previous measurement becomes an input
        (x_k = (F - J H) x_(k-1) + J z_(k-1) + v_k - J w_(k-1), J = S R^-1, process covariance
        Q - J S^T): the accelerometers then act kinematically on the velocities, whatever the SM's
        force balance predicts.

    Returns
    -------
    AlignmentEstimate
    """
    if smoother not in ("rts", "none"):
        raise ValueError(f"smoother must be 'rts' or 'none', got {smoother!r}")
    fw = _ForwardFilter(p, t_s, speed_m_s, measurements, R=R, Q=Q, noise=noise, curvature_1_m=curvature_1_m,
                        smoother=smoother, initial_covariance=initial_covariance, S=S)
    return fw.smoothed(fw.run(fw.n), 0, fw.n, np.asarray(s_m, float))


class _ForwardFilter:
    """The forward filter of :func:`estimate` (Eq. 18-24), run over a record in consecutive pieces
    (:meth:`run`), and the smoother over any stretch of what it stored (:meth:`smoothed`): a long
    record is smoothed in overlapping windows (:func:`estimate_in_blocks`) while the filter runs on."""

    def __init__(self, p, t_s, speed_m_s, measurements, R=None, Q=None, noise=None, curvature_1_m=None,
                 smoother="rts", initial_covariance=None, S=None):
        from filterpy.kalman import KalmanFilter

        t = np.asarray(t_s, float)
        n = len(t)
        zm = np.asarray(measurements, float)
        if zm.shape != (n, 3):
            raise ValueError(f"measurements must have shape ({n}, 3), got {zm.shape}")
        if n < 2:
            raise ValueError("need at least two samples")
        dts = np.diff(t)
        dt = float(np.median(dts))
        if not (dt > 0 and np.allclose(dts, dt, rtol=1e-3, atol=1e-9)):
            raise ValueError("sample times must be uniform and increasing")
        noise = noise or NoiseDensities()
        R = noise.r() if R is None else np.asarray(R, float)
        v = np.broadcast_to(np.asarray(speed_m_s, float), t.shape)
        if not np.all(v > 0):
            raise ValueError("speed must be > 0 m/s throughout (the SM's creep damping goes with 1/V)")
        kap = np.zeros(n) if curvature_1_m is None else np.broadcast_to(np.asarray(curvature_1_m, float), t.shape)
        self.curved = bool(np.any(kap != 0))

        bins = np.round(v / SPEED_BIN_M_S).astype(np.int64)
        ubins, which = np.unique(bins, return_inverse=True)
        models = [discrete_model(p, b * SPEED_BIN_M_S, dt, Q=Q, noise=noise) for b in ubins]
        H = models[0].H
        J = None
        if S is not None:
            S = np.asarray(S, float)
            J = S @ np.linalg.inv(R)
            models = [DiscreteModel(m.F - J @ H, m.G, H, m.D, 0.5 * ((m.Q - J @ S.T) + (m.Q - J @ S.T).T))
                      for m in models]
        # measurements with the known curvature feed removed
        Dk = np.stack([mdl.D[:, 0] for mdl in models])[which] * kap[:, None]
        self.z = np.column_stack([zm, np.zeros(n)]) - Dk
        self.t, self.n, self.kap, self.which, self.models, self.H, self.J, self.S = t, n, kap, which, models, H, J, S
        self.smoother = smoother
        self.ns = models[0].F.shape[0]
        kf = KalmanFilter(dim_x=self.ns, dim_z=N_MEAS, dim_u=1)
        kf.H = H
        kf.R = R
        kf.x = np.zeros((self.ns, 1))
        kf.P = _initial_covariance(p.state_kinds) if initial_covariance is None else np.asarray(initial_covariance, float)
        self.kf = kf
        self.k = 0                       # the next sample to filter
        self.d = np.zeros(self.ns)       # deterministic response to the curvature input

    def run(self, stop: int) -> dict:
        """Filter the samples from the next one to ``stop`` - 1; returns their arrays: the posterior
        states and covariances Xf, Pf, the priors Xp, Pp (with S), the error transitions Af (without
        the smoother), the innovations Nu normalized by their predicted sigmas, and det, the
        deterministic curvature response (curved track without S)."""
        k0, ns, S, kf, H, models, which, kap = self.k, self.ns, self.S, self.kf, self.H, self.models, self.which, self.kap
        m = stop - k0
        z = self.z[k0:stop]
        zcol = z[:, :, None]
        Jz = None if S is None else self.z[max(k0 - 1, 0):stop] @ self.J.T   # J z_k, input of step k + 1
        jo = 1 if k0 else 0
        Xp = np.empty((m, ns)) if S is not None else None      # priors for the smoother with inputs
        Pp = np.empty((m, ns, ns)) if S is not None else None
        Xf = np.empty((m, ns))
        Pf = np.empty((m, ns, ns))
        Af = np.empty((m, ns, ns)) if self.smoother == "none" else None
        Nu = np.empty((m, N_MEAS))       # innovations, then normalized by their predicted sigmas
        Su = np.empty((m, N_MEAS))
        det = np.zeros((m, ns)) if (self.curved and S is None) else None
        d = self.d
        u = np.zeros((1, 1))
        for i in range(m):
            k = k0 + i
            if k:
                mdl = models[which[k]]
                kf.F, kf.Q, kf.B = mdl.F, mdl.Q, mdl.G
                u[0, 0] = kap[k - 1]
                kf.predict(u=u)
                if S is not None:
                    kf.x[:, 0] += Jz[i - 1 + jo]
                    Xp[i], Pp[i] = kf.x[:, 0], kf.P
                elif det is not None:
                    d = mdl.F @ d + mdl.G[:, 0] * kap[k - 1]
                    det[i] = d
            kf.update(zcol[i])
            Nu[i] = kf.y[:, 0]
            Su[i] = kf.S.diagonal()
            Xf[i] = kf.x[:, 0]
            Pf[i] = kf.P
            if Af is not None:
                Af[i] = (np.eye(ns) - kf.K @ H) @ models[which[k]].F
        self.d, self.k = d, stop
        Nu /= np.sqrt(Su)
        return {"start": k0, "Xf": Xf, "Pf": Pf, "Xp": Xp, "Pp": Pp, "Af": Af, "Nu": Nu, "det": det}

    def smoothed(self, fwd: dict, lo: int, hi: int, s_m: np.ndarray) -> AlignmentEstimate:
        """The estimate of the samples lo..hi - 1 (indices of the record; ``fwd`` holds them, as made
        by :meth:`run` or joined by :func:`_join`): the RTS smoother started at sample hi - 1 from the
        filter's posterior there (the whole record's smoother when hi is its end), or the filter."""
        from filterpy.kalman import rts_smoother

        a, b = lo - fwd["start"], hi - fwd["start"]
        Xf, Pf = fwd["Xf"][a:b], fwd["Pf"][a:b]
        models, which = self.models, self.which[lo:hi]
        if self.smoother == "rts" and self.S is not None:
            X, P, trans = _rts_from_priors(Xf, Pf, fwd["Xp"][a:b], fwd["Pp"][a:b], [models[w].F for w in which])
        elif self.smoother == "rts":
            det = fwd["det"][a:b] if fwd["det"] is not None else np.zeros_like(Xf)
            # filterpy's F[k] takes step k to k + 1; ours (models[which[k]]) takes k - 1 to k
            Fs = [models[w].F for w in which[1:]] + [models[which[-1]].F]
            Qs = [models[w].Q for w in which[1:]] + [models[which[-1]].Q]
            Xs, Ps, trans, _ = rts_smoother((Xf - det)[:, :, None], Pf, Fs, Qs)
            X, P = Xs[:, :, 0] + det, Ps
        else:
            X, P, trans = Xf, Pf, fwd["Af"][a:b]
        if self.smoother == "rts":
            # The RTS covariance update P_k + C_k (P_(k+1)^s - P_(k+1|k)) C_k^T cancels badly right after a
            # wide P0 (stiff dynamics, exact accelerometers) and can leave a negative variance in the first
            # samples; the filter's P_k, which the smoothed one never exceeds, is used there instead.
            bad = np.any(np.einsum("kii->ki", P) < 0.0, axis=1)
            if bad.any():
                P = P.copy()
                P[bad] = Pf[bad]
        sig = np.sqrt(np.maximum(np.einsum("kii->ki", P), 0.0))
        return AlignmentEstimate(self.t[lo:hi], s_m[lo:hi], X, sig, Xf, self.smoother, trans,
                                 P[:, :, XI_INDEX].copy(), fwd["Nu"][a:b])


def _join(old: dict | None, new: dict, lo: int) -> dict:
    """The forward filter's arrays of ``old`` from sample lo on, followed by ``new``'s."""
    if old is None or lo >= new["start"]:
        return new
    a = lo - old["start"]
    return {"start": lo, **{key: None if v is None else np.concatenate([v[a:], new[key]])
                            for key, v in old.items() if key != "start"}}


def innovation_rms(est: AlignmentEstimate, skip_m: float = SETTLE_M) -> np.ndarray:
    """Root mean square of the forward filter's normalized innovations per channel.

    Parameters
    ----------
    est : result of :func:`estimate`.
    skip_m : chainage at the start left out (the filter's start-up from its wide P0).

    Returns
    -------
    (4,) rms of innovation / predicted sigma for [wheelset acc, gyro, frame acc, virtual xi]. With
    the model and the noises exactly right every entry is 1 (the innovations are then white with
    covariance H P H^T + R: Kalman 1960, Mehra 1970). On real data the calibrated covariances absorb
    model error, so the values are not 1; what carries information is their ratio to the same
    figure on the calibration runs (identification.model_consistency).

    References
    ----------
    R. K. Mehra, "On the identification of variances and adaptive Kalman filtering", IEEE Trans.
    Automatic Control 15 (1970) 175-184 (innovation whiteness and covariance as a model check).
    """
    if est.normalized_innovations is None:
        raise ValueError("the estimate carries no innovations")
    use = est.s_m >= est.s_m[0] + skip_m
    if not use.any():
        raise ValueError(f"the record is shorter than skip_m = {skip_m} m")
    return np.sqrt(np.mean(np.square(est.normalized_innovations[use]), axis=0))


def _coarse_alignment_covariance(est: AlignmentEstimate, idx: np.ndarray) -> np.ndarray:
    """Covariance of the alignment errors at the samples ``idx`` (m x m), equally spaced but the
    last step, which may be shorter.

    The smoother's errors obey e_k = C_k e_(k+1) + u_k with u_k independent of every later error,
    so Cov(e_k, e_j) = C_k ... C_(j-1) P_j for k < j (Rauch et al. 1965); the forward filter's obey
    e_j = A_j e_(j-1) + u_j, so Cov(e_j, e_k) = A_j ... A_(k+1) P_k for j > k. The products over
    each step of ``idx`` are formed batched; one pass over the chosen samples then carries the xi
    columns of P through them for all samples at once.
    """
    m = len(idx)
    steps = np.diff(idx)       # equal but the last, which ends at the record's last sample
    T = est.transitions
    ns = T.shape[1]
    G = np.broadcast_to(np.eye(ns), (max(m - 1, 0), ns, ns)).copy()
    for r in range(int(steps.max()) if m > 1 else 0):
        on = r < steps
        k = idx[:-1][on]
        if est.smoother == "rts":          # C_k C_(k+1) ... C_(k+d-1), k = idx[c]
            G[on] = G[on] @ T[k + r]
        else:                              # A_(k+d) ... A_(k+1)
            G[on] = T[k + 1 + r] @ G[on]
    W = np.zeros((ns, m))
    C = np.zeros((m, m))
    P = est.cov_xi[idx]
    if est.smoother == "rts":
        for c in range(m - 1, -1, -1):
            if c < m - 1:
                W[:, c + 1:] = G[c] @ W[:, c + 1:]
            W[:, c] = P[c]
            C[c, c:] = W[XI_INDEX, c:]
        return np.triu(C) + np.triu(C, 1).T
    for c in range(m):
        if c:
            W[:, :c] = G[c - 1] @ W[:, :c]
        W[:, c] = P[c]
        C[c, :c + 1] = W[XI_INDEX, :c + 1]
    return np.tril(C) + np.tril(C, -1).T


def _interpolation_matrix(x: np.ndarray, grid: np.ndarray):
    """Sparse (G, len(x)) matrix of linear interpolation from the increasing points x to grid."""
    from scipy.sparse import csr_matrix

    j = np.clip(np.searchsorted(x, grid, side="right") - 1, 0, len(x) - 2)
    w = np.clip((grid - x[j]) / (x[j + 1] - x[j]), 0.0, 1.0)
    rows = np.repeat(np.arange(len(grid)), 2)
    return csr_matrix((np.column_stack([1.0 - w, w]).ravel(), (rows, np.column_stack([j, j + 1]).ravel())),
                      shape=(len(grid), len(x)))


@lru_cache(maxsize=4)
def _bandpass_matrix(n: int, step_m: float, short_m: float, long_m: float) -> np.ndarray:
    """trolley.bands.bandpass_wavelength as an (n, n) matrix (read-only; the blocks of a long
    record share it)."""
    from trolley.bands import bandpass_wavelength

    B = bandpass_wavelength(np.eye(n), step_m, short_m, long_m, axis=0)
    B.setflags(write=False)
    return B


#: grid step (m) of the band-passed alignment and its sigma, and the block length and margin (in long
#: wavelengths) they are formed in
BAND_STEP_M = 0.5
BAND_BLOCK_M = 1000.0
BAND_MARGIN_WAVES = 2.0
#: how far beyond a block's band window the smoother of :func:`estimate_in_blocks` is run, in long
#: wavelengths of the band
SMOOTHER_AHEAD_WAVES = 2.0


def band_error_covariance(est: AlignmentEstimate, short_m: float, long_m: float, sigma_scale: float = 1.0):
    """Covariance of the band-passed alignment error between all points of a record's grid,
    B Cov(e) B^T (:func:`band_alignment` gives its diagonal), for records of at most one block.

    With it the spread that honest sigmas leave in one record's rms(error / sigma) follows: that
    rms is a quadratic form of a Gaussian vector with this covariance (see
    :func:`honesty_spread`).

    Returns
    -------
    grid_m : (G,) chainages, m (the grid of :func:`band_alignment`).
    covariance : (G, G) m^2, times sigma_scale^2.
    """
    from trolley.bands import bandpass_wavelength

    s = np.asarray(est.s_m, float)
    if s[-1] - s[0] > 1.5 * BAND_BLOCK_M:
        raise ValueError(f"band_error_covariance covers records up to {1.5 * BAND_BLOCK_M:g} m")
    h = BAND_STEP_M
    grid = s[0] + h * np.arange(int(np.floor((s[-1] - s[0]) / h + 1e-9)) + 1)
    d = max(1, int(round(h / float(np.median(np.diff(s))))))
    idx = np.unique(np.r_[np.arange(0, len(s), d), len(s) - 1])
    L = _interpolation_matrix(s[idx], grid)
    Cg = L @ (L @ _coarse_alignment_covariance(est, idx)).T
    BC = bandpass_wavelength(Cg, h, short_m, long_m, axis=0)
    cov = bandpass_wavelength(np.ascontiguousarray(BC.T), h, short_m, long_m, axis=0)
    return grid, sigma_scale ** 2 * 0.5 * (cov + cov.T)


def honesty_spread(covariance: np.ndarray, low: float = 0.7, high: float = 1.3, j_limit_m: float | None = None,
                   draws: int = 20000, seed: int = 0) -> tuple[float, float, float | None]:
    """How one record's rms(error / sigma) and J = rms(error) scatter when the sigmas are exactly right.

    ``draws`` records of errors are drawn from N(0, covariance); each record's rms(error / sigma),
    sigma = sqrt(diag(covariance)), and rms(error) are formed.

    Returns
    -------
    effective_samples : n^2 / tr(R^2), R the correlation matrix: the number of independent
        samples the record is worth.
    p_honest : fraction of records whose rms(error / sigma) lies in [low, high].
    p_j : fraction of records whose J is at most ``j_limit_m`` (None without a limit).
    """
    sd = np.sqrt(np.diag(covariance))
    R = covariance / np.outer(sd, sd)
    w, U = np.linalg.eigh(R)
    w = np.clip(w, 0.0, None)
    z = (np.random.default_rng(seed).standard_normal((draws, len(w))) * np.sqrt(w)) @ U.T
    rms = np.sqrt(np.mean(z ** 2, axis=1))
    p_j = None if j_limit_m is None else float(np.mean(np.sqrt(np.mean((z * sd) ** 2, axis=1)) <= j_limit_m))
    return float(len(w) ** 2 / np.sum(w ** 2)), float(np.mean((rms >= low) & (rms <= high))), p_j


def band_alignment(est: AlignmentEstimate, short_m: float, long_m: float, sigma_scale: float = 1.0,
                   truth_m=None, block_m: float | None = None):
    """The alignment band-passed to short_m-long_m (the EN 13848 wavelength range, trolley.bands)
    and the 1-sigma of that band-passed estimate, on a uniform grid of :data:`BAND_STEP_M`.

    The band-passed error is B e with B the (linear) band-pass, so its covariance is
    B Cov(e) B^T; Cov(e) between the samples follows from the filter's or the smoother's own error
    recursion (:func:`_coarse_alignment_covariance`). Waves longer than ``long_m``, which the
    in-service sensors barely observe and which dominate the error of the unfiltered alignment,
    then no longer enter the sigma.

    Records longer than :data:`BAND_BLOCK_M` are band-passed in blocks of that length, each
    filtered over a window reaching :data:`BAND_MARGIN_WAVES` long wavelengths beyond it on both
    sides (trolley.bands: the D3 filter's leakage is 1.2e-2 two waves from a window end), so that
    the estimate and its sigma come from the same operator and the work grows linearly with the
    length. A record shorter than one block is filtered whole, exactly as ``bandpass_wavelength``.

    Parameters
    ----------
    est : result of :func:`estimate`.
    short_m, long_m : band limits (wavelengths), m.
    sigma_scale : calibration factor of the sigmas (identification.EstimatorModel.sigma_scale).
    truth_m : optional (N,) true alignment at ``est.s_m``, band-passed by the same operator.
    block_m : block length, m (default :data:`BAND_BLOCK_M`).

    Returns
    -------
    grid_m : (G,) chainages, m.
    alignment_m : (G,) band-passed estimate, m.
    sigma_m : (G,) its 1-sigma, m.
    truth_band_m : (G,) the band-passed truth (only when ``truth_m`` is given).
    """
    if est.transitions is None or est.cov_xi is None:
        raise ValueError("band_alignment needs an estimate made by estimate()")
    s = np.asarray(est.s_m, float)
    grid = _band_grid(s, long_m)
    d = _coarse_step(s)
    values = [est.alignment_m] + ([np.asarray(truth_m, float)] if truth_m is not None else [])
    out = np.empty((len(values) + 1, len(grid)))
    for w, keep in _band_blocks(grid, BAND_BLOCK_M if block_m is None else block_m, BAND_MARGIN_WAVES * long_m):
        lo, hi = _window_samples(s, grid[w])
        _band_window(est, lo, hi, grid[w], d, short_m, long_m, values, out, np.flatnonzero(w)[keep], keep)
    res = (grid, out[0], sigma_scale * out[-1])
    return res + (out[1],) if truth_m is not None else res


def _band_grid(s: np.ndarray, long_m: float) -> np.ndarray:
    """The grid of :func:`band_alignment` over the chainages s."""
    h = BAND_STEP_M
    grid = s[0] + h * np.arange(int(np.floor((s[-1] - s[0]) / h + 1e-9)) + 1)
    if grid[-1] - grid[0] < long_m:
        raise ValueError(f"a {grid[-1] - grid[0]:.1f} m record cannot hold waves of {long_m} m")
    return grid


def _coarse_step(s: np.ndarray) -> int:
    """Samples per step of the band grid."""
    return max(1, int(round(BAND_STEP_M / float(np.median(np.diff(s))))))


def _band_blocks(grid: np.ndarray, block_m: float, margin_m: float):
    """The blocks a long record is band-passed (and smoothed) in: for each, the window of the grid
    it is filtered over (a mask of ``grid``: the block and ``margin_m`` on both sides, cut at the
    record's ends) and the block's own points within that window (a mask of ``grid[window]``). A
    rest of up to half a block joins the last block; a record of up to 1.5 blocks is one block."""
    start = grid[0]
    while True:
        stop = grid[-1] if grid[-1] - start <= 1.5 * block_m else start + block_m
        w = (grid >= start - margin_m - 1e-9) & (grid <= stop + margin_m + 1e-9)
        g = grid[w]
        yield w, (g >= start - 1e-9) & ((g < stop - 1e-9) | (stop >= grid[-1]))
        if stop >= grid[-1]:
            return
        start = stop


def _window_samples(s: np.ndarray, g: np.ndarray) -> tuple[int, int]:
    """The samples lo..hi - 1 of the chainages s that cover the window grid g."""
    lo = max(np.searchsorted(s, g[0], side="right") - 1, 0)
    hi = min(np.searchsorted(s, g[-1]) + 1, len(s))
    return int(lo), int(hi)


def _band_window(est, lo, hi, g, d, short_m, long_m, values, out, rows, keep) -> None:
    """One window of :func:`band_alignment`: the band-passed ``values`` (at est.s_m) and the band
    sigma over the window grid g from the samples lo..hi - 1 of ``est``, the points ``keep`` of g
    written to the columns ``rows`` of ``out`` (values first, the sigma last)."""
    from trolley.bands import bandpass_wavelength

    s, h = est.s_m, BAND_STEP_M
    idx = np.unique(np.r_[np.arange(lo, hi, d), hi - 1])
    L = _interpolation_matrix(s[idx], g)
    Cg = L @ (L @ _coarse_alignment_covariance(est, idx)).T
    # diag(B Cg B^T) with B the band-pass as a matrix: filtering the columns of Cg gives B Cg,
    # O(G^2) instead of a G^3 product
    B = _bandpass_matrix(len(g), h, short_m, long_m)
    var = np.sum(bandpass_wavelength(Cg, h, short_m, long_m, axis=0) * B, axis=1)
    for r, v in enumerate(values):
        out[r, rows] = bandpass_wavelength(np.interp(g, s, v), h, short_m, long_m)[keep]
    out[-1, rows] = np.sqrt(np.maximum(var[keep], 0.0))


@dataclass
class AlignmentProfile:
    """Result of :func:`estimate_in_blocks`: the alignment and its sigma at every sample, the forward
    filter's normalized innovations (as in :class:`AlignmentEstimate`, so :func:`innovation_rms`
    takes it) and the band-passed alignment of :func:`band_alignment`, without the states and their
    covariances (which a long record cannot hold).

    Attributes
    ----------
    t_s, s_m : (N,) sample times (s) and chainages (m).
    alignment_m, sigma_alignment_m : (N,) estimated alignment xi and its 1-sigma (not scaled), m.
    normalized_innovations : (N, 4) as in :class:`AlignmentEstimate`.
    smoother : "rts" or "none".
    band : (grid_m, alignment_m, sigma_m[, truth_band_m]) as :func:`band_alignment` returns, or None.
    blocks : number of blocks the record was smoothed in (1: :func:`estimate` on the whole record).
    """

    t_s: np.ndarray
    s_m: np.ndarray
    alignment_m: np.ndarray
    sigma_alignment_m: np.ndarray
    normalized_innovations: np.ndarray
    smoother: str
    band: tuple | None
    blocks: int


def estimate_in_blocks(p: DesignParameters, t_s, s_m, speed_m_s, measurements, band_m=None,
                       sigma_scale: float = 1.0, truth_m=None, block_m: float | None = None,
                       **kwargs) -> AlignmentProfile:
    """:func:`estimate` and :func:`band_alignment` with memory bounded by the block, not the record.

    The forward filter runs over the whole record and keeps only the samples of the current
    window; the smoother and the band sigma run per block of :func:`band_alignment` (the same
    blocks: :data:`BAND_BLOCK_M` and :data:`BAND_MARGIN_WAVES` long wavelengths of margin on both
    sides), the smoother started at the window's last sample from the filter's posterior there,
    and the block's own samples and grid points are kept. The smoother of a window then misses the
    sensors beyond the margin, which it has forgotten by then (docs/inservice.md, "Long
    recordings"). A record of one block (at most 1.5 ``block_m``), or without a band, is
    :func:`estimate` and :func:`band_alignment` themselves, to the bit.

    Parameters
    ----------
    p, t_s, s_m, speed_m_s, measurements, **kwargs : as :func:`estimate` (R, Q, noise,
        curvature_1_m, smoother, initial_covariance, S).
    band_m : (short_m, long_m) of the band-passed alignment, or None (no band, no blocks).
    sigma_scale, truth_m : as :func:`band_alignment`.
    block_m : block length, m (default :data:`BAND_BLOCK_M`).

    Returns
    -------
    AlignmentProfile
    """
    s = np.asarray(s_m, float)
    block_m = BAND_BLOCK_M if block_m is None else float(block_m)
    grid = _band_grid(s, band_m[1]) if band_m is not None else None
    if grid is None or grid[-1] - grid[0] <= 1.5 * block_m:
        est = estimate(p, t_s, s, speed_m_s, measurements, **kwargs)
        band = None if band_m is None else band_alignment(est, *band_m, sigma_scale=sigma_scale, truth_m=truth_m,
                                                          block_m=block_m)
        return AlignmentProfile(est.t_s, est.s_m, est.alignment_m, est.sigma_alignment_m,
                                est.normalized_innovations, est.smoother, band, 1)
    smoother = kwargs.pop("smoother", "rts")
    if smoother not in ("rts", "none"):
        raise ValueError(f"smoother must be 'rts' or 'none', got {smoother!r}")
    fw = _ForwardFilter(p, t_s, speed_m_s, measurements, smoother=smoother, **kwargs)
    n = fw.n
    xi, sig, nu = np.empty(n), np.empty(n), np.empty((n, N_MEAS))
    d = _coarse_step(s)
    truth = None if truth_m is None else np.asarray(truth_m, float)
    out = np.empty((2 + (truth is not None), len(grid)))
    fwd, blocks = None, 0
    for w, keep in _band_blocks(grid, block_m, BAND_MARGIN_WAVES * band_m[1]):
        g = grid[w]
        lo, hi = _window_samples(s, g)
        # the smoother looks further ahead than the band's window: the unfiltered alignment's long
        # waves are remembered over several hundred metres
        ahead = min(int(np.searchsorted(s, g[-1] + SMOOTHER_AHEAD_WAVES * band_m[1])) + 1, n)
        if g[-1] >= grid[-1]:
            ahead = n   # the last block keeps the samples beyond the grid's last point (< one step)
        if ahead > fw.k:
            new = fw.run(ahead)
            nu[new["start"]:ahead] = new["Nu"]
            fwd = _join(fwd, new, lo)
        est = fw.smoothed(fwd, lo, ahead, s)
        # the block's own samples: from its first grid point to (not including) the next block's
        gk = g[keep]
        a = int(np.searchsorted(s, gk[0] - 1e-9))
        b = n if gk[-1] >= grid[-1] else int(np.searchsorted(s, gk[-1] + BAND_STEP_M - 1e-9))
        xi[a:b], sig[a:b] = est.alignment_m[a - lo:b - lo], est.sigma_alignment_m[a - lo:b - lo]
        values = [est.alignment_m] + ([truth[lo:ahead]] if truth is not None else [])
        _band_window(est, 0, hi - lo, g, d, band_m[0], band_m[1], values, out, np.flatnonzero(w)[keep], keep)
        blocks += 1
        del est
    band = (grid, out[0], sigma_scale * out[-1]) + ((out[1],) if truth is not None else ())
    return AlignmentProfile(fw.t, s, xi, sig, nu, smoother, band, blocks)
