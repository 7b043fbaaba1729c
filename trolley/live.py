"""Incremental processing for the field session: one interval at a time (Jiang 2017 Sec. 2, 4.3).

The paper's own scheme: "when the system comes across a landmark, a position observation updates,
and the Kalman filtering and smoothing algorithm is executed to output the optimized position
measurements of the interval". :class:`LiveProcessor` keeps the dead reckoning and the forward
filter's posterior at the last accepted fix; a new fix filters the nodes since then and the
interval between the two fixes is smoothed (fixed-interval RTS), in a time that does not grow
with the length of the session. The final track of a session is still computed by
:func:`trolley.engine.process_session` over everything (it also uses later fixes and
relinearises).

The same models serve both: error models, node grid, P0, noise and fix covariances all come from
``trolley.engine`` and ``trolley.error_models``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from trolley.deadreckoning import (DeadReckoning, StaticAlignment, dead_reckon, mounting_rotation,
                                   static_alignment, stop_levels)
from trolley.engine import (ProcessConfig, Stations, Trajectory, _interp_nodes, _POS, error_model, filter_noise,
                            filter_nodes, fix_covariances, fix_matrices, grid_to_ned, initial_covariance,
                            make_stations, ned_to_grid, sigmas_to_grid, turn_sigmas)
from trolley.projection import GridFactors, site_factors
from trolley.session import Fixes, RawSession, SessionMeta
from trolley.smoothers import ForwardResult, Measurements, forward_filter, gate_threshold, rts_smooth, state_scale


@dataclass
class FixVerdict:
    """What the gate said of one fix."""

    point: str
    t_s: float
    accepted: bool
    nis: float
    innovation_enh_m: np.ndarray
    reason: str


@dataclass
class IntervalResult:
    """The interval between the two last accepted fixes, smoothed."""

    stations: Stations
    max_abs_lateral_dev_m: float
    max_abs_vertical_dev_m: float
    max_sigma_m: float
    gauge_range_m: tuple[float, float]
    cant_range_m: tuple[float, float]
    seconds: float


@dataclass
class _FixState:
    t_s: float
    point: str
    enh_m: np.ndarray
    sigma_m: np.ndarray
    block: int
    x: np.ndarray
    P: np.ndarray
    roll_error_rad: float
    forward: object = None  # forward results of the interval this fix closed
    F: np.ndarray | None = None
    Q: np.ndarray | None = None
    nodes: np.ndarray | None = None
    block_start: int = 0


@dataclass
class _Samples:
    chunks: list = field(default_factory=list)

    def add(self, *arrays) -> None:
        if arrays[0] is not None and len(arrays[0]):
            self.chunks.append(tuple(np.asarray(a, dtype=float) for a in arrays))

    def arrays(self, n: int):
        if not self.chunks:
            return tuple(np.empty((0,) + ((3,) if i else ())) for i in range(n))
        if len(self.chunks) > 1:
            self.chunks = [tuple(np.concatenate([c[i] for c in self.chunks]) for i in range(n))]
        return self.chunks[0]


class LiveProcessor:
    """Interval-by-interval filtering and smoothing during a survey.

    Parameters
    ----------
    meta : session metadata (site, trolley, IMU and odometer figures, fix sigma).
    design : ``trolley.alignment.Alignment`` or None.
    config : processing settings (the same as the final processing).
    grid : the project grid at the site (``trolley.projection.GridFactors``, e.g. at the CPIII
        centroid); None with ``meta.crs`` takes it at the first fix; without a CRS the grid is a
        local true-north map, as in :func:`trolley.engine.process_session`.
    """

    def __init__(self, meta: SessionMeta, design=None, config: ProcessConfig = ProcessConfig(),
                 grid: GridFactors | None = None):
        if meta.imu is None:
            raise ValueError("the session has no IMU figures: the filter needs them")
        self.meta = meta
        self.design = design
        self.config = config
        self._imu = _Samples()
        self._odo = _Samples()
        self._gauge = _Samples()
        self.alignment: StaticAlignment | None = None
        self._dr: DeadReckoning | None = None
        self._dr_until = -np.inf
        self._fixes: list[_FixState] = []  # one per stop with an accepted fix
        self._accepted: list[tuple] = []  # every accepted fix measurement
        self._undo: list[tuple] = []
        self._P0 = None
        self._origin = None
        self._p0 = None
        self._grid = grid
        self._noise = filter_noise(meta, config)
        self._misalign = meta.trolley.imu_misalignment_rad
        self._lever = np.asarray(meta.trolley.prism_lever_arm_m, dtype=float)

    # --- data in -------------------------------------------------------------------------
    def align(self, imu_t_s, imu_w_rad_s, imu_f_m_s2) -> StaticAlignment:
        """Initial alignment from the static period's samples (which are kept as data)."""
        imu = self.meta.imu
        t = np.asarray(imu_t_s, dtype=float)
        self.alignment = static_alignment(
            t, np.asarray(imu_w_rad_s, float), np.asarray(imu_f_m_s2, float), np.inf, self.meta.latitude_rad,
            self._misalign, initial_heading_rad=self.meta.initial_heading_rad,
            gyro_bias_rad_s=imu.gyro_bias_sigma_rad_s, accel_bias_m_s2=imu.accel_bias_m_s2,
            gyrocompassing=imu.gyrocompassing, given_heading_sigma_rad=self.config.given_heading_sigma_rad)
        if self.alignment.heading_source == "fixes":
            raise ValueError("this IMU cannot gyrocompass: give initial_heading_deg for a live session")
        self._imu.add(t, imu_w_rad_s, imu_f_m_s2)
        self._P0, self.heading_sigma_rad = initial_covariance(self.meta, self.alignment, float(t[-1] - t[0]),
                                                              self.config)
        return self.alignment

    def add_samples(self, imu_t_s, imu_w_rad_s, imu_f_m_s2, odo_t_s, odo_distance_m,
                    gauge_t_s=None, gauge_m=None) -> None:
        """New samples since the last call, in time order."""
        self._imu.add(imu_t_s, imu_w_rad_s, imu_f_m_s2)
        self._odo.add(odo_t_s, odo_distance_m)
        if gauge_t_s is not None:
            self._gauge.add(gauge_t_s, gauge_m)

    # --- dead reckoning ----------------------------------------------------------------------
    def _dead_reckon(self) -> DeadReckoning:
        """Extend the dead reckoning over the samples that arrived since the last call."""
        t, w, f = self._imu.arrays(3)
        odo_t, odo_d = self._odo.arrays(2)
        if self.alignment is None:
            raise RuntimeError("align() first")
        if odo_t.size == 0:  # standing still since the alignment: the odometer reads zero
            odo_t, odo_d = np.array([t[0], t[-1]]), np.zeros(2)
        if self._dr is None:
            self._dr = dead_reckon(t, w, odo_t, odo_d, self.alignment, self.meta.latitude_rad,
                                   self.meta.height_m, self._misalign, self.config.block_size)
            self._dr_until = self._dr.t_s[-1]
            return self._dr
        if t[-1] <= self._dr_until:
            return self._dr
        b_to_bt = mounting_rotation(self._misalign)
        last = self._dr
        cont = StaticAlignment(last.trolley_to_nav[-1] * b_to_bt, 0.0, 0.0, 0.0, 0.0, 0.0, "continued",
                               float(last.t_s[-1]))
        i0 = max(int(np.searchsorted(t, last.t_s[-1])) - 0, 0)
        j0 = max(int(np.searchsorted(odo_t, last.t_s[-1])) - 2, 0)
        new = dead_reckon(t[i0:], w[i0:], odo_t[j0:], odo_d[j0:], cont, self.meta.latitude_rad,
                          self.meta.height_m, self._misalign, self.config.block_size)
        # new starts at the last block of the old one: append from its second block
        self._dr = DeadReckoning(
            t_s=np.concatenate([last.t_s, new.t_s[1:]]),
            distance_m=np.concatenate([last.distance_m, new.distance_m[1:]]),
            trolley_to_nav=Rotation.concatenate([last.trolley_to_nav, new.trolley_to_nav[1:]]),
            position_ned_m=np.concatenate([last.position_ned_m, last.position_ned_m[-1] + new.position_ned_m[1:]]))
        self._dr_until = self._dr.t_s[-1]
        return self._dr

    def _roll_error_at(self, t_fix: float) -> float:
        t, w, f = self._imu.arrays(3)
        odo_t, odo_d = self._odo.arrays(2)
        if odo_t.size == 0:
            odo_t, odo_d = np.array([t[0], t[-1]]), np.zeros(2)
        roll, _ = stop_levels(t, f, odo_t, odo_d, np.array([t_fix]), self._misalign, w_rad_s=w)
        if not np.isfinite(roll[0]) or not self.config.level_at_stops:
            return 0.0
        dr = self._dr
        roll_dr = float(np.interp(t_fix, dr.t_s, dr.euler_rad()[:, 0]))
        return float(np.angle(np.exp(1j * (roll_dr - roll[0]))))

    # --- fixes ------------------------------------------------------------------------------
    def add_fix(self, t_s: float, point: str, enh_m, sigma_m=None, force_accept: bool = False,
                cov_m2=None) -> FixVerdict:
        """Gate one prism fix against the prediction; an accepted fix closes an interval.

        ``sigma_m`` (3,) its grid E, N, H 1-sigma (None: the session's ``fix_sigma_m``); ``cov_m2``
        (3,) the covariances E-N, E-H, N-H (``Fixes.cov_m2``; None: 0)."""
        enh = np.asarray(enh_m, dtype=float)
        sig = np.full(3, self.meta.fix_sigma_m) if sigma_m is None else np.asarray(sigma_m, dtype=float)
        cov = np.zeros(3) if cov_m2 is None else np.asarray(cov_m2, dtype=float).reshape(3)
        dr = self._dead_reckon()
        block = int(np.clip(np.searchsorted(dr.t_s, t_s), 0, dr.t_s.size - 1))
        roll_err = self._roll_error_at(t_s)
        att = dr.trolley_to_nav[block] * Rotation.from_rotvec([-roll_err, 0.0, 0.0])
        lever_ned = att.apply(self._lever)
        if not self._fixes:
            self._origin = enh.copy()
            if self._grid is None and self.meta.crs:
                self._grid = site_factors(self.meta.crs, enh[None])
            self._p0 = grid_to_ned(enh[None], self._origin, self._grid)[0] - lever_ned - dr.position_ned_m[block]
            x_prev, P_prev, b_prev = np.zeros(8), self._P0, block
        else:
            prev = self._fixes[-1]
            x_prev, P_prev, b_prev = prev.x, prev.P, prev.block
        z = self._p0 + dr.position_ned_m[block] + lever_ned - grid_to_ned(enh[None], self._origin, self._grid)[0]
        if self._fixes and block > b_prev:
            sub = _slice(dr, b_prev, block + 1)
            nodes = filter_nodes(sub, np.array([0, block - b_prev]), self.config.node_spacing_m,
                                 self.config.max_node_dt_s)
            F, Q = error_model(sub, nodes, self._noise, *turn_sigmas(self.meta, self.config))
        else:
            nodes, F, Q = np.array([0]), np.zeros((0, 8, 8)), np.zeros((0, 8, 8))
        prior_P = P_prev
        H = fix_matrices(lever_ned[None], np.array([att.as_euler("ZYX")[0]]))
        R = fix_covariances(Fixes(np.zeros(1), np.array([point], dtype=object), enh[None], sig[None],
                                  cov[None]).covariance_enh_m2(), self._grid)
        meas = Measurements(np.array([len(nodes) - 1]), z[None], H, R)
        if self._fixes and block == b_prev:
            prior_P = P_prev  # a repeated fix at the same stop: no motion in between
        fwd = forward_filter(F, Q, x_prev, prior_P, meas, gate_probability=self.config.gate_probability,
                             force_accept=np.array([force_accept]))
        y = fwd.innovation[0]
        innov = np.array([y[1], y[0], -y[2]])
        if self._grid is not None:
            innov = self._grid.local_to_grid(innov)
        accepted = bool(fwd.accepted[0])
        thr = gate_threshold(self.config.gate_probability, 3) if self.config.gate_probability else np.inf
        if accepted:
            reason = "accepted by the crew despite the gate" if fwd.nis[0] > thr else ""
            self._undo.append((list(self._fixes), list(self._accepted)))
            self._accepted.append((float(t_s), str(point), enh, sig, cov))
            state = _FixState(float(t_s), str(point), enh, sig, block, fwd.x_post[-1], fwd.P_post[-1],
                              roll_err, fwd if self._fixes else None, F, Q, nodes, b_prev)
            prev = self._fixes[-1] if self._fixes else None
            if prev is not None and dr.travel_m[block] - dr.travel_m[prev.block] < 0.05:
                # another fix at the same stop: the interval now ends here, its filter run extended
                if prev.forward is not None:
                    off = prev.block - prev.block_start
                    state.forward = ForwardResult(
                        *(np.concatenate([getattr(prev.forward, k), getattr(fwd, k)[1:]])
                          for k in ("x_prior", "P_prior", "x_post", "P_post")),
                        fwd.innovation, fwd.innovation_cov, fwd.nis, fwd.accepted)
                    state.F = np.concatenate([prev.F, F])
                    state.Q = np.concatenate([prev.Q, Q])
                    state.nodes = np.concatenate([prev.nodes, off + nodes[1:]])
                    state.block_start = prev.block_start
                else:
                    state.forward, state.F, state.Q, state.nodes, state.block_start = None, None, None, None, block
                self._fixes[-1] = state
            else:
                self._fixes.append(state)
        else:
            reason = (f"innovation NIS {fwd.nis[0]:.1f} > {thr:.1f} (chi-square gate, 3 dof): "
                      f"re-measure, or accept if the prism and the station are right")
        return FixVerdict(str(point), float(t_s), accepted, float(fwd.nis[0]), innov, reason)

    def undo_last_fix(self) -> bool:
        """Forget the last accepted fix (the crew's undo); False when there is none."""
        if not self._undo:
            return False
        self._fixes, self._accepted = self._undo.pop()
        return True

    @property
    def fixes(self) -> Fixes:
        """The accepted fixes so far."""
        a = self._accepted
        return Fixes(np.array([x[0] for x in a]), np.array([x[1] for x in a], dtype=object),
                     np.array([x[2] for x in a]).reshape(-1, 3), np.array([x[3] for x in a]).reshape(-1, 3),
                     np.array([x[4] for x in a]).reshape(-1, 3))

    # --- results ----------------------------------------------------------------------------
    def smooth_last_interval(self) -> IntervalResult:
        """RTS-smooth the interval closed by the last accepted fix and resample it on stations."""
        t0 = time.perf_counter()
        if len(self._fixes) < 2:
            raise RuntimeError("an interval needs two accepted fixes")
        last, prev = self._fixes[-1], self._fixes[-2]
        sm = rts_smooth(last.F, last.Q, last.forward, scale=state_scale(self._P0))
        sub = _slice(self._dr, last.block_start, last.block + 1)
        xb = _interp_nodes(sub, last.nodes, sm.x)
        var = _interp_nodes(sub, last.nodes, np.diagonal(sm.P, axis1=1, axis2=2)[:, _POS])
        ned = self._p0 + sub.position_ned_m - xb[:, _POS]
        sig = np.sqrt(np.maximum(var, 0.0))
        roll_err = np.interp(sub.t_s, [sub.t_s[0], last.t_s], [prev.roll_error_rad, last.roll_error_rad])
        roll = sub.euler_rad()[:, 0] - roll_err
        traj = Trajectory(sub.t_s, sub.travel_m, ned_to_grid(ned, self._origin, self._grid),
                          sigmas_to_grid(np.column_stack([sig[:, 1], sig[:, 0], sig[:, 2]]), self._grid), roll, xb,
                          odometer_m=sub.distance_m)
        gt, gm = self._gauge.arrays(2)
        session = RawSession(self.meta, np.empty(0), np.empty((0, 3)), np.empty((0, 3)), np.empty(0), np.empty(0),
                             self.fixes, gt if gt.size else None, gm if gm.size else None)
        st = make_stations(traj, session, self.design, self.config)

        def rng(x):
            x = x[np.isfinite(x)]
            return (float(x.min()), float(x.max())) if x.size else (float("nan"), float("nan"))

        def amax(x):
            x = x[np.isfinite(x)]
            return float(np.abs(x).max()) if x.size else float("nan")

        smax = np.column_stack([st.sigma_E_m, st.sigma_N_m, st.sigma_H_m])
        return IntervalResult(st, amax(st.lateral_dev_m), amax(st.vertical_dev_m),
                              float(np.nanmax(smax)) if smax.size else float("nan"),
                              rng(st.gauge_m), rng(st.cant_m), time.perf_counter() - t0)

    def position_now(self) -> tuple[float, float, float, float, float, float]:
        """(chainage, E, N, H, predicted horizontal 1-sigma, distance since the last fix) now."""
        dr = self._dead_reckon()
        if not self._fixes:
            raise RuntimeError("no fix yet")
        last = self._fixes[-1]
        b = dr.t_s.size - 1
        if b > last.block:
            sub = _slice(dr, last.block, b + 1)
            F, Q = error_model(sub, np.array([0, b - last.block]), self._noise, *turn_sigmas(self.meta, self.config))
            x = F[0] @ last.x
            P = F[0] @ last.P @ F[0].T + Q[0]
        else:
            x, P = last.x, last.P
        ned = self._p0 + dr.position_ned_m[b] - x[_POS]
        E, N, H = ned_to_grid(ned[None], self._origin, self._grid)[0]
        chain = float(self.design.project(np.array([E]), np.array([N]), np.array([H])).chainage_m[0]) \
            if self.design is not None else float(dr.travel_m[b])
        sigma_h = float(np.sqrt(0.5 * (P[0, 0] + P[1, 1])))
        travel = dr.travel_m
        return chain, float(E), float(N), float(H), sigma_h, float(travel[b] - travel[last.block])


def _slice(dr: DeadReckoning, i: int, j: int) -> DeadReckoning:
    return DeadReckoning(dr.t_s[i:j], dr.distance_m[i:j], dr.trolley_to_nav[i:j], dr.position_ned_m[i:j])


#: variance given to the closing fix of the budget interval to make it carry no information (m^2):
#: its gain ``C / V`` is then below 1e-15, so the smoothed variance is the filtered one to 1e-15
_NO_FIX_VAR_M2 = 1e12


def dead_reckoning_sigma(case, distance_m: float, elapsed_s: float) -> dict[str, float]:
    """Predicted 1-sigma of the position at the trolley, from the budget model (Jiang 2017 Sec. 5).

    The filtered (not yet smoothed) error ``r(t) = r0 + v * integral a`` of the budget model
    (``trolley.budget``, module docstring) after dead reckoning ``distance_m`` in ``elapsed_s``
    since the last fix, at the constant speed ``v = distance_m / elapsed_s`` that covers the same
    distance in the same time: ``A(t) = p_r + p_a d^2 + q d^2 t / 3 + p_b d^2 t^2 / 4`` with
    ``d = v t``. It is the smoothed variance (Eq. 40/44/45, ``trolley.budget.smoothed_variance``)
    at the end of an interval whose closing fix carries no information, so it grows without bound
    past the planned fix spacing, while the smoothed sigma of a planned interval stays bounded.

    Parameters
    ----------
    case : ``trolley.budget.BudgetCase`` (its spacing and speed are not used).
    distance_m : odometer distance since the last fix, m (its absolute value is used).
    elapsed_s : session time since the last fix, s.

    Returns
    -------
    dict direction -> 1-sigma, m (``trolley.budget.DIRECTIONS``).
    """
    from dataclasses import replace

    from trolley.budget import DIRECTIONS, channel_parameters, smoothed_variance

    d = abs(float(distance_m))
    t = max(float(elapsed_s), 0.0)
    v = d / t if t > 0.0 else 0.0
    out = {}
    for direction in DIRECTIONS:
        c = replace(channel_parameters(case, direction), fix_var=np.asarray(_NO_FIX_VAR_M2))
        out[direction] = float(np.sqrt(smoothed_variance(t, t, v, c)))
    return out
