"""The stop-and-go survey engine: dead reckoning, error-state filtering and smoothing, track output.

Jiang 2017 Sec. 2-4 end to end:

1. static alignment and dead reckoning (``trolley.deadreckoning``, Eq. 7);
2. a node grid along the trajectory (every ``node_spacing_m`` of travel, every ``max_node_dt_s``
   when standing, at every fix, and where the trolley starts or stops): the error filters need
   not run at the IMU rate;
3. the vertical (3-state) and level (5-state) error models (``trolley.error_models``, Eq. 17-25),
   discretised exactly per node interval (Van Loan) with that interval's odometer speed and
   heading, run as one block-diagonal 8-state filter so that a fix is gated once on its 3-D
   innovation (chi-square, 3 degrees of freedom);
4. prism fixes as measurements of the dead-reckoning error after the prism lever arm is removed
   with the dead-reckoned attitude (roll = cant);
5. RTS (filterpy) or two-filter smoothing (``trolley.smoothers``, Eq. 27-28), and the smoothed
   errors subtracted from the dead-reckoned trajectory between every pair of fixes;
6. stations on a fixed chainage step, with deviations from the design when there is one.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
from scipy.linalg import block_diag

from trolley import error_models as em
from trolley.projection import GridFactors, session_site
from trolley.deadreckoning import (DeadReckoning, StaticAlignment, dead_reckon, handling_blocks, mounting_rotation,
                                   levelled_stop_times, quat_multiply, static_alignment, stop_levels,
                                   with_roll_levelled)
from trolley.session import RawSession
from trolley.smoothers import (SNOOP_OUT_PROBABILITY, Measurements, SmoothedResult, forward_filter, gate_threshold,
                               rts_smooth, snooped_verdicts, state_scale, two_filter_smooth)
from trolley.trackgeometry import TrackInput

#: Passes the data snooping may add (each when it changed a verdict); the third run of the
#: snooping ends the loop whatever it found.
SNOOPING_PASSES = 2

#: Grid stations this far beyond the first or last projected chainage are still output.
STATION_END_TOLERANCE_M = 0.005

_STATION_FIELDS = ("chainage_m", "E_m", "N_m", "H_m", "sigma_E_m", "sigma_N_m", "sigma_H_m", "lateral_dev_m",
                   "vertical_dev_m", "gauge_m", "cant_m", "twist_m", "t_s", "cov_EN_m2", "sigma_cant_m")

#: Order of the combined 8-state error vector: level channel then vertical channel.
STATE_NAMES = em.LEVEL_STATES + em.VERTICAL_STATES
_IDX_N, _IDX_E, _IDX_D = 0, 1, 5
_IDX_HEADING, _IDX_PITCH = 3, 6  # the equivalent heading and pitch errors
_POS = [_IDX_N, _IDX_E, _IDX_D]


@dataclass(frozen=True)
class ProcessConfig:
    """Settings of :func:`process_session`.

    Attributes
    ----------
    smoother : "rts", "tfs" or "none" (filtered only).
    step_m : chainage step of the output stations.
    node_spacing_m : distance between filter nodes while moving.
    placement_sigma_m : along-track 1-sigma of where a trolley the crew lifted off the track (or
        turned) is put back (:func:`with_crew_handling`).
    max_node_dt_s : longest time between filter nodes (standing still, or creeping).
    gate_probability : chi-square gate of the fixes (None: accept all).
    block_size : IMU samples per dead-reckoning step.
    bias_correlation_s : correlation time of the gyro bias instability; the equivalent bias is
        given a random walk sigma_BI sqrt(2 / tau) so that the filter can follow it.
    residual_level_rad : equivalent level error from the IMU-odometer misalignment left after
        calibration (Jiang 2017 Sec. 5 uses 0.005 deg in all).
    given_heading_sigma_rad : uncertainty of a heading given in session.toml.
    prior_position_m : 1-sigma of the position before the first fix.
    twist_base_m : base of the twist column.
    force_accept : point labels whose fixes skip the gate (the crew accepted them).
    level_at_stops : re-level the roll from the accelerometers at every stop
        (:func:`trolley.deadreckoning.stop_levels`).
    relinearisations : extra filter passes on the dead reckoning corrected with the previous
        pass's attitude and scale estimates (see :func:`corrected_dead_reckoning`).
    relinearise_above_rad : ... but only when an estimated equivalent attitude error exceeds this
        (or the scale error 1e-3): at 3 mrad the second-order error of the linear model is
        phi^2/2 = 4.5e-6 of the distance, a constant scale that the odometer state absorbs.
    """

    smoother: str = "rts"
    step_m: float = 0.625
    # 5 m: between nodes the position errors are interpolated in distance, and they grow
    # smoothly (Eq. 18, 23): pooled over 3 simulated 1.2 km sessions the RMS errors against truth
    # at 5 m equal those at 2 m to 0.1 um (RLG), 0.2 um (FOG), 3.4 um (MEMS), at 40 % of the nodes
    node_spacing_m: float = 5.0
    # where along the track a lifted trolley is put back, 1-sigma (a few centimetres in practice)
    placement_sigma_m: float = 0.05
    max_node_dt_s: float = 10.0
    gate_probability: float | None = 0.9999
    block_size: int = 40
    bias_correlation_s: float = 1000.0
    residual_level_rad: float = float(np.deg2rad(0.003))
    given_heading_sigma_rad: float = float(np.deg2rad(0.5))
    prior_position_m: float = 0.1
    twist_base_m: float = 3.0
    force_accept: tuple[str, ...] = ()
    relinearisations: int = 1
    relinearise_above_rad: float = 3e-3
    level_at_stops: bool = True


@dataclass
class FixReport:
    """Every fix with its innovation (DR prism minus measured, grid E, N, H) and the gate's verdict."""

    t_s: np.ndarray
    point: np.ndarray
    enh_m: np.ndarray
    innovation_enh_m: np.ndarray
    nis: np.ndarray
    accepted: np.ndarray
    reason: list[str]


@dataclass
class Stations(TrackInput):
    """Output stations: the track table of ``trolley.trackgeometry`` plus what the engine knows
    besides (SI; NaN where a value is not available).

    Attributes
    ----------
    twist_m : cant difference over ``ProcessConfig.twist_base_m``.
    t_s : time the trolley passed the station.
    """

    twist_m: np.ndarray | None = None
    t_s: np.ndarray | None = None


@dataclass
class Trajectory:
    """The corrected trajectory of the track reference point at dead-reckoning resolution.

    ``distance_m`` is the distance travelled (never decreasing); ``odometer_m`` the signed
    odometer, which counts down while the trolley runs turned around (None: never turned).
    """

    t_s: np.ndarray
    distance_m: np.ndarray
    enh_m: np.ndarray
    sigma_enh_m: np.ndarray
    roll_rad: np.ndarray
    error_states: np.ndarray  # (K, 8) smoothed (or filtered) error estimate
    odometer_m: np.ndarray | None = None
    #: (K,) covariance of grid E and N, m^2 (None: not known, taken as 0)
    cov_EN_m2: np.ndarray | None = None
    #: (K,) 1-sigma of the roll, rad: the stops' level and the gyro drift between levelled stops
    #: (:func:`trolley.error_models.levelled_roll_variance`); None: not known
    roll_sigma_rad: np.ndarray | None = None


@dataclass
class ProcessResult:
    """Everything :func:`process_session` produces."""

    stations: Stations
    trajectory: Trajectory
    fixes: FixReport
    alignment: StaticAlignment
    dead_reckoning: DeadReckoning
    observability_ranks: tuple[int, int] | None
    config: ProcessConfig
    node_count: int
    summary: dict = field(default_factory=dict)


def _ned(enh: np.ndarray, origin_enh: np.ndarray) -> np.ndarray:
    d = enh - origin_enh
    return np.column_stack([d[:, 1], d[:, 0], -d[:, 2]])


def _enh(ned: np.ndarray, origin_enh: np.ndarray) -> np.ndarray:
    return np.column_stack([ned[:, 1], ned[:, 0], -ned[:, 2]]) + origin_enh


def grid_to_ned(enh: np.ndarray, origin_enh: np.ndarray, grid: GridFactors | None) -> np.ndarray:
    """Grid E, N, H to the filter's local NED about ``origin_enh``: with a projected grid, turned to
    true north and brought to ground scale (``GridFactors.grid_to_local``); without, swapped only."""
    if grid is None:
        return _ned(enh, origin_enh)
    d = grid.grid_to_local(enh - origin_enh)
    return np.column_stack([d[:, 1], d[:, 0], -d[:, 2]])


def ned_to_grid(ned: np.ndarray, origin_enh: np.ndarray, grid: GridFactors | None) -> np.ndarray:
    """The inverse of :func:`grid_to_ned`."""
    if grid is None:
        return _enh(ned, origin_enh)
    return origin_enh + grid.local_to_grid(np.column_stack([ned[:, 1], ned[:, 0], -ned[:, 2]]))


def sigmas_to_grid(sigma_enh: np.ndarray, grid: GridFactors | None) -> np.ndarray:
    """1-sigmas along true east / north to grid E / N (the E-N correlation is dropped)."""
    if grid is None:
        return sigma_enh
    vE, vN, _ = horizontal_covariance_to_grid(sigma_enh[:, 0] ** 2, sigma_enh[:, 1] ** 2, 0.0, grid)
    out = sigma_enh.copy()
    out[:, 0], out[:, 1] = np.sqrt(vE), np.sqrt(vN)
    return out


def horizontal_covariance_to_grid(var_E, var_N, cov_EN, grid: GridFactors | None):
    """Variances and covariance along true east / north turned into grid E / N (exactly, unlike
    :func:`sigmas_to_grid`): ``k R C R^T k`` with R the convergence rotation of
    :meth:`trolley.projection.GridFactors.local_to_grid`.

    Returns
    -------
    var_E, var_N, cov_EN : grid variances and covariance, m^2.
    """
    if grid is None:
        return var_E, var_N, cov_EN
    c, s, k2 = np.cos(grid.convergence_rad), np.sin(grid.convergence_rad), grid.combined_scale ** 2
    vE = k2 * (c * c * var_E - 2 * c * s * cov_EN + s * s * var_N)
    vN = k2 * (s * s * var_E + 2 * c * s * cov_EN + c * c * var_N)
    cEN = k2 * (c * s * (var_E - var_N) + (c * c - s * s) * cov_EN)
    return vE, vN, cEN


def level_sigma_rad(align: StaticAlignment, config: ProcessConfig) -> float:
    """1-sigma of the level (roll and pitch) the alignment leaves: accelerometer bias / g and the
    residual mounting error in quadrature (the filter's P0 of the equivalent pitch; the roll, not
    a filter state, keeps it: it is the cant's error)."""
    return float(np.hypot(align.level_sigma_rad, config.residual_level_rad))


class GridRotationError(ValueError):
    """Most fixes were rejected and they are turned, consistently, against the dead reckoning."""


#: :func:`check_rotation` refuses a session when more than this share of the fixes after the
#: first is rejected and a rotation explains the rest.
ROTATION_REJECTED_SHARE = 0.5
#: A rotation of the fixes beyond this many heading sigmas is no heading error of the alignment
#: (P = 6e-5 at 4). It was 5 while the heading sigma held the in-run bias only; with the whole
#: bias (ImuFigures.gyro_bias_sigma_rad_s, sqrt(2) larger) 5 sigmas let 0.96 deg of convergence
#: 200 km off a UTM meridian at 28 deg N pass unexplained: 4 of 4 fixes rejected, exit 0.
ROTATION_SIGMAS = 4.0


def fix_rotation(dr: DeadReckoning, fix_blocks: np.ndarray, fix_ned: np.ndarray, lever: np.ndarray
                 ) -> tuple[float, float, float, float]:
    """The rotation and scale that best turn the dead-reckoned prism path onto the fixes.

    With z = N + iE the horizontal displacements from the first fix (dead reckoning a, fixes b),
    the least-squares similarity b ~ s e^{i theta} a has e^{i theta} along sum(conj(a) b) and
    s = |sum(conj(a) b)| / sum(|a|^2) (the 2-D Procrustes solution; Umeyama 1991, Eq. 40-42).
    theta is the azimuth of the fixes minus that of the dead reckoning: a grid of convergence
    gamma, taken as true north, gives theta = -gamma.

    Returns
    -------
    (theta_rad, scale, rms before, rms after): the rotation, the scale, and the RMS horizontal
    misclosure of the fixes before and after the similarity, m.
    """
    pos = dr.position_ned_m[fix_blocks] + dr.trolley_to_nav[fix_blocks].apply(lever)
    a = (pos[:, 0] - pos[0, 0]) + 1j * (pos[:, 1] - pos[0, 1])
    b = (fix_ned[:, 0] - fix_ned[0, 0]) + 1j * (fix_ned[:, 1] - fix_ned[0, 1])
    c = np.sum(np.conj(a) * b)
    aa = float(np.sum(np.abs(a) ** 2))
    if aa == 0.0 or c == 0:
        return 0.0, 1.0, 0.0, 0.0
    theta = float(np.angle(c))
    scale = float(abs(c) / aa)
    before = float(np.sqrt(np.mean(np.abs(b - a) ** 2)))
    after = float(np.sqrt(np.mean(np.abs(b - scale * np.exp(1j * theta) * a) ** 2)))
    return theta, scale, before, after


def check_rotation(dr: DeadReckoning, fix_blocks: np.ndarray, fix_ned: np.ndarray, lever: np.ndarray,
                   accepted: np.ndarray, heading_sigma_rad: float, grid: GridFactors | None) -> None:
    """Refuse a session whose fixes were mostly rejected because they are turned against true north.

    The dead reckoning's heading is true (gyrocompassing, or a given true heading); fixes in a
    projected grid are turned by the grid convergence. A convergence far beyond the heading's
    1-sigma makes the gate reject the fixes one after another, and the track drifts off by the
    angle times the distance. When more than :data:`ROTATION_REJECTED_SHARE` of the fixes after
    the first are rejected and one rotation (:func:`fix_rotation`) larger than :data:`ROTATION_SIGMAS`
    heading sigmas
    explains at least 90 % of their misclosure, this raises with the angle and what to do.

    Raises
    ------
    GridRotationError
    """
    later = accepted[1:]
    if later.size < 2 or np.mean(~later) <= ROTATION_REJECTED_SHARE:
        return
    theta, scale, before, after = fix_rotation(dr, fix_blocks, fix_ned, lever)
    if abs(theta) <= max(ROTATION_SIGMAS * heading_sigma_rad, 1e-4) or after > 0.1 * before:
        return
    n_rej, n = int((~later).sum()), int(later.size)
    deg = float(np.rad2deg(theta))
    what = (f"{n_rej} of the {n} fixes after the first were rejected: the fixes are turned by {deg:+.4f} deg "
            f"against the dead reckoning's true north, consistently (misclosure {before:.3f} m rms, "
            f"{after:.3f} m after turning them back; scale {scale:.6f})")
    if grid is None:
        raise GridRotationError(
            f"{what}. That is what the grid convergence of a map projection does ({-deg:+.4f} deg here; "
            "0.96 deg 200 km off a UTM central meridian at 28 deg N): give the project's coordinate reference "
            "system ([site] crs = \"EPSG:...\" in session.toml, or `trolley project set-crs`), and the engine "
            "turns true north into grid north. If the grid is a local one with true north, the initial "
            "heading is off by that much instead")
    raise GridRotationError(
        f"{what}, after the convergence of {grid.convergence_rad * 180 / np.pi:+.4f} deg of the CRS given was "
        "applied: check the CRS (its zone) and the initial heading")


#: The fixes observe the position errors N, E, D of the 8-state vector.
FIX_H = np.zeros((3, 8))
FIX_H[0, _IDX_N] = FIX_H[1, _IDX_E] = FIX_H[2, _IDX_D] = 1.0


def fix_matrices(lever_ned_m: np.ndarray, yaw_rad: np.ndarray) -> np.ndarray:
    """(M, 3, 8) measurement matrices of prism fixes with the lever arm's attitude error.

    The prism is the reference point plus the lever arm L = C_bt^n l, put into the navigation
    frame with the dead-reckoned attitude; with ``C_est = (I - [phi x]) C_true`` (Jiang 2017
    Eq. 8) its error is ``L x phi``, and the equivalent pitch and heading errors of the states
    make ``phi = [-sin(psi) phi_pitch, cos(psi) phi_pitch, phi_D]`` (Eq. 4; roll is levelled at
    the stops). With the prism right above the reference point this is the pitch error times the
    mast height; with the prism off to one side, the heading error moves it sideways, and by the
    opposite amount once the crew has turned the trolley around.
    """
    L = np.atleast_2d(lever_ned_m)
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    H = np.broadcast_to(FIX_H, (L.shape[0], 3, 8)).copy()
    H[:, 0, _IDX_HEADING] = L[:, 1]
    H[:, 1, _IDX_HEADING] = -L[:, 0]
    H[:, 0, _IDX_PITCH] = -L[:, 2] * c
    H[:, 1, _IDX_PITCH] = -L[:, 2] * s
    H[:, 2, _IDX_PITCH] = L[:, 0] * c + L[:, 1] * s
    return H


def turn_sigmas(meta, config: ProcessConfig) -> tuple[float, float, float]:
    """1-sigma of the jumps of the equivalent pitch and heading errors when the crew turns the
    trolley around (:func:`with_crew_handling`): twice the residual mounting error, and pi times the
    gyro scale-factor error; and of the along-track placement of a handled trolley."""
    return 2.0 * config.residual_level_rad, float(np.pi * meta.imu.gyro_scale_factor), config.placement_sigma_m


def filter_noise(meta, config: ProcessConfig) -> em.ChannelNoise:
    """Process noise of the error filters from the datasheet figures in the session metadata."""
    imu = meta.imu
    return em.ChannelNoise(
        gyro_arw_rad_sqrt_s=imu.gyro_arw_rad_sqrt_s,
        odo_scale_noise_per_sqrt_s=meta.odometer.scale_noise_per_sqrt_s,
        gyro_bias_rw_rad_s_sqrt_s=imu.gyro_bias_instability_rad_s * np.sqrt(2.0 / config.bias_correlation_s))


def initial_covariance(meta, align: StaticAlignment, static_s: float, config: ProcessConfig
                       ) -> tuple[np.ndarray, float]:
    """P0 of the 8-state filter at the first node, and the heading 1-sigma it uses.

    Level: accelerometer bias / g with the residual mounting error in quadrature. Heading: the
    alignment's (gyrocompassing: bias / (omega_ie cos L), plus the angle random walk over the
    static window). Equivalent biases: Jiang 2017 Eq. 6 via
    :func:`trolley.error_models.equivalent_gyro_bias`.
    """
    imu = meta.imu
    heading_sigma = align.heading_sigma_rad
    if align.heading_source == "gyrocompassing":
        heading_sigma = float(np.hypot(heading_sigma, em.heading_error_from_gyrocompassing(
            imu.gyro_arw_rad_sqrt_s / np.sqrt(max(static_s, 1.0)), meta.latitude_rad)))
    # the bias the filter starts from is the whole bias (turn-on and in-run), as is the one the
    # gyrocompassing turned into the heading error
    eq_bias = float(em.equivalent_gyro_bias(imu.gyro_bias_sigma_rad_s, heading_sigma, meta.latitude_rad))
    p0u = em.InitialUncertainty(
        position_m=config.prior_position_m,
        pitch_rad=level_sigma_rad(align, config),
        heading_rad=heading_sigma, gyro_bias_y_rad_s=eq_bias, gyro_bias_z_rad_s=eq_bias,
        odo_scale_error=meta.odometer.scale_error)
    return block_diag(em.level_initial_covariance(p0u), em.vertical_initial_covariance(p0u)), heading_sigma


def longest_run(flags: np.ndarray) -> int:
    """Length of the longest run of consecutive True values."""
    f = np.concatenate(([0], np.asarray(flags, dtype=np.int8), [0]))
    edges = np.flatnonzero(np.diff(f))
    return int(np.max(edges[1::2] - edges[::2])) if edges.size else 0


def fix_covariances(covariance_enh_m2: np.ndarray, grid: GridFactors | None = None) -> np.ndarray:
    """(n, 3, 3) noise covariances of fixes in the filter's N, E, D frame from their grid E, N, H
    covariances (``Fixes.covariance_enh_m2``): ``L C L^T`` with L the linear part of
    :func:`grid_to_ned` (with a projected grid, turned by the convergence and scaled; without, the
    axes swapped), so that a fix's correlations turn with it."""
    L = grid_to_ned(np.eye(3), np.zeros(3), grid).T  # column j: the image of the grid's unit axis j
    c = np.asarray(covariance_enh_m2, dtype=float).reshape(-1, 3, 3)
    return L @ c @ L.T


def filter_nodes(dr: DeadReckoning, fix_blocks: np.ndarray, node_spacing_m: float,
                 max_node_dt_s: float) -> np.ndarray:
    """Indices of the DR blocks used as filter nodes (sorted, unique).

    Besides the distance and time grids and the fixes, a node sits wherever the trolley starts or
    stops: an interval that mixes standing and moving would get one mean speed in the model, and
    the states interpolated linearly in time across it would spread the motion's position error
    change over the standing part (a heading error of 3 mrad makes that 3 mm per metre).
    """
    K = dr.t_s.shape[0]
    travel = dr.travel_m
    by_dist = np.flatnonzero(np.diff(np.floor(travel / node_spacing_m)) != 0) + 1
    moving = np.diff(travel) > 0  # block k -> k+1
    starts_stops = np.flatnonzero(np.diff(moving.astype(np.int8)) != 0) + 1
    base = np.unique(np.concatenate([[0, K - 1], by_dist, starts_stops, fix_blocks]))
    # then a node every max_node_dt_s inside any longer gap (standing, or creeping slowly): a
    # fixed time grid would add nodes between the distance nodes of a trolley that moves
    gap = np.searchsorted(base, np.arange(K), side="right") - 1
    phase = np.floor((dr.t_s - dr.t_s[base[gap]]) / max_node_dt_s)
    by_time = np.flatnonzero((np.diff(phase) > 0) & (np.diff(gap) == 0)) + 1
    return np.unique(np.concatenate([base, by_time]))


def interval_motion(dr: DeadReckoning, idx: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Duration, mean odometer speed and mean north and east velocity between consecutive DR blocks ``idx``.

    The means are the interval's odometer distance and dead-reckoned displacement divided by its
    duration (zero for an interval of zero duration).
    """
    dt = np.diff(dr.t_s[idx])
    safe = np.where(dt > 0, dt, 1.0)
    speed = np.where(dt > 0, np.diff(dr.distance_m[idx]) / safe, 0.0)
    dpos = np.diff(dr.position_ned_m[idx], axis=0)
    vn = np.where(dt > 0, dpos[:, 0] / safe, 0.0)
    ve = np.where(dt > 0, dpos[:, 1] / safe, 0.0)
    return dt, speed, vn, ve


def discrete_model(speed: np.ndarray, vn: np.ndarray, ve: np.ndarray, noise: em.ChannelNoise, dt
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(n, 8, 8) F and Q of the combined model (level then vertical channel, Eq. 19, 24) over steps dt (Van Loan)."""
    Al, Gl = em.level_matrices(vn, ve)
    Av, Gv = em.vertical_matrices(speed)
    Fl, Ql = em.van_loan(Al, Gl, em.level_noise_psd(noise), dt)
    Fv, Qv = em.van_loan(Av, Gv, em.vertical_noise_psd(noise), dt)
    n = Fl.shape[0]
    F = np.zeros((n, 8, 8))
    Q = np.zeros((n, 8, 8))
    F[:, :5, :5], F[:, 5:, 5:] = Fl, Fv
    Q[:, :5, :5], Q[:, 5:, 5:] = Ql, Qv
    return F, Q


def error_model(dr: DeadReckoning, nodes: np.ndarray, noise: em.ChannelNoise,
                turn_pitch_sigma_rad: float = 0.0, turn_heading_sigma_rad: float = 0.0,
                placement_sigma_m: float = 0.0, handling=None) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation of the 8-state error model between consecutive nodes.

    The interval's speed and heading enter through its mean odometer speed and mean north and
    east velocity (:func:`interval_motion`). ``handling``: see :func:`with_crew_handling`.
    """
    dt, speed, vn, ve = interval_motion(dr, nodes)
    F, Q = discrete_model(speed, vn, ve, noise, dt)
    return with_crew_handling(F, Q, dr, nodes, turn_pitch_sigma_rad, turn_heading_sigma_rad, placement_sigma_m,
                              handling=handling)


_HEADING, _PITCH = _IDX_HEADING, _IDX_PITCH


def with_crew_handling(F: np.ndarray, Q: np.ndarray, dr: DeadReckoning, nodes: np.ndarray,
                  pitch_sigma_rad: float = 0.0, heading_sigma_rad: float = 0.0,
                  placement_sigma_m: float = 0.0, handling=None) -> tuple[np.ndarray, np.ndarray]:
    """F and Q with the crew's handling of the trolley (:func:`trolley.deadreckoning.handling_blocks`):
    lifted off the track (a train) or turned around, and put back.

    Put back on the rails, the reference point is again on the track centre line, but the
    odometer did not count where along the track: its position error gains ``placement_sigma_m``
    along the track, in 3-D (the dead-reckoned heading and pitch where it stopped: on a grade the
    point put back further along is higher or lower too, 0.26 mm for 3 cm on 8.6 mrad, which a
    fix of 0.06 mm in height sees), and the next fix takes it.

    The error states are those of the trolley frame (Jiang 2017 Eq. 14-16). Turning the trolley
    by 180 deg about its z axis keeps the navigation-frame attitude error but reverses the
    trolley's y axis, so the equivalent pitch error changes sign, while the heading error (about
    z), the gyro biases (fixed to the IMU), the odometer scale factor and the position errors are
    unchanged; the odometer speed of Eq. 18 then changes sign too, so ``v * phi_pitch`` keeps
    driving the height error the same way. The turn is applied at the end of the node interval
    in which it happens (the trolley stands: nothing else moves then).

    The equivalent pitch error holds the residual IMU-to-trolley mounting error eps too (Eq. 14),
    which is fixed to the trolley and does not change sign: after the turn it is
    ``-phi_pitch_eq + 2 eps``. The model has no state for eps, so ``2 eps`` enters as process
    noise of sigma ``pitch_sigma_rad`` (twice the residual mounting sigma) at the turn: slightly
    conservative, as it forgets that eps is partly known from the fixes before the turn.
    Likewise the z gyro's scale-factor error sf turns the heading by ``pi sf`` during the turn;
    ``heading_sigma_rad`` (pi times the scale-factor figure) enters the equivalent heading error.

    ``handling``: the result of ``handling_blocks(dr)`` when the caller has it already (a
    relinearisation pass's corrected dead reckoning stands and turns where the original did).
    """
    blocks, turned, psi, theta = handling_blocks(dr) if handling is None else handling
    if blocks.size == 0 or F.shape[0] == 0:
        return F, Q
    interval = np.clip(np.searchsorted(nodes, blocks, side="left") - 1, 0, F.shape[0] - 1)
    F, Q = F.copy(), Q.copy()
    # along the track: the heading and pitch the trolley had when it stopped (not the turning one)
    along = np.column_stack([np.cos(theta) * np.cos(psi), np.cos(theta) * np.sin(psi), -np.sin(theta)])  # N, E, D
    for i, a in zip(interval, along):  # one per handling, a few per session
        Q[i][np.ix_(_POS, _POS)] += placement_sigma_m ** 2 * np.outer(a, a)
    flips = np.bincount(interval[turned], minlength=F.shape[0]) % 2 == 1
    if not flips.any():
        return F, Q
    T = np.ones(8)
    T[_PITCH] = -1.0
    F[flips] *= T[:, None]
    Q[flips] *= T[:, None] * T[None, :]
    Q[flips, _PITCH, _PITCH] += pitch_sigma_rad ** 2
    Q[flips, _HEADING, _HEADING] += heading_sigma_rad ** 2
    return F, Q


def _interp_rows(x_new: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """np.interp of every column of a (K, ...) array."""
    flat = y.reshape(y.shape[0], -1)
    out = np.empty((x_new.shape[0], flat.shape[1]))
    for j in range(flat.shape[1]):  # a handful of state/covariance columns, not samples
        out[:, j] = np.interp(x_new, x, flat[:, j])
    return out.reshape((x_new.shape[0],) + y.shape[1:])


def _interp_nodes(dr: DeadReckoning, nodes: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Node values (K_nodes, ...) at every DR block, linear in the odometer distance between nodes.

    The position errors grow with the distance travelled (Jiang 2017 Eq. 18, 23: their rate is
    v times an angle), so between two nodes they are interpolated in distance; in time they would
    be wrong by heading error x (distance - distance linear in time), about 1 mm while the trolley
    decelerates over a metre with a 3 mrad heading error. Where the trolley stands between two
    nodes the fraction is taken in time. ``nodes`` must hold the first and last block.
    """
    k = np.arange(dr.t_s.shape[0])
    j = np.clip(np.searchsorted(nodes, k, side="right") - 1, 0, len(nodes) - 2)
    a, b = nodes[j], nodes[j + 1]
    travel = dr.travel_m
    dd = travel[b] - travel[a]
    dt = dr.t_s[b] - dr.t_s[a]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(dd > 0, (travel - travel[a]) / np.where(dd > 0, dd, 1.0),
                        np.where(dt > 0, (dr.t_s - dr.t_s[a]) / np.where(dt > 0, dt, 1.0), 0.0))
    frac = np.clip(frac, 0.0, 1.0).reshape((-1,) + (1,) * (y.ndim - 1))
    return y[j] + frac * (y[j + 1] - y[j])


def process_session(session: RawSession, design=None, config: ProcessConfig = ProcessConfig(),
                    with_observability: bool = True,
                    progress: Callable[[str, float], None] | None = None) -> ProcessResult:
    """Filter and smooth one raw session into a track.

    Parameters
    ----------
    session : the raw session.
    design : a ``trolley.alignment.Alignment`` or None.
    config : processing settings.
    with_observability : also report the observability ranks of the session's own interval
        models (python-control; about 2 s to import), see :func:`session_observability_ranks`.
    progress : optional callable ``progress(step, fraction)``: the step under way (e.g.
        "forward filter, pass 1 of 2") and the fraction of the whole run done, 0..1, called at
        every sub-step and every few hundred filter nodes.

    Returns
    -------
    ProcessResult

    Raises
    ------
    ValueError when the session cannot be processed (no fixes, no IMU data in the static period,
    no moving data); the message says why.
    """
    def report(step: str, fraction: float) -> None:
        if progress is not None:
            progress(step, float(min(max(fraction, 0.0), 1.0)))

    def within(step: str, start: float, end: float) -> Callable[[float], None] | None:
        # a sub-step's own fraction mapped onto [start, end] of the whole run
        if progress is None:
            return None
        return lambda f: report(step, start + (end - start) * f)

    meta, grid = session_site(session.meta, session.fixes.enh_m)
    if meta is not session.meta:  # the latitude derived from the CRS at the fixes
        session = replace(session, meta=meta)
    imu = meta.imu
    if imu is None:
        raise ValueError("session.toml has no [imu] figures: the filter needs them for Q and P0")
    if len(session.fixes) == 0:
        raise ValueError("fixes.csv holds no fix: at least the fix of the first stop is needed")
    lever = np.asarray(meta.trolley.prism_lever_arm_m, dtype=float)
    misalign = meta.trolley.imu_misalignment_rad
    report("static alignment", 0.0)
    align = static_alignment(
        session.imu_t_s, session.imu_w_rad_s, session.imu_f_m_s2, meta.static_s, meta.latitude_rad,
        misalign, initial_heading_rad=meta.initial_heading_rad,
        gyro_bias_rad_s=imu.gyro_bias_sigma_rad_s, accel_bias_m_s2=imu.accel_bias_m_s2,
        gyrocompassing=imu.gyrocompassing, given_heading_sigma_rad=config.given_heading_sigma_rad)
    report("dead reckoning", 0.02)
    dr = dead_reckon(session.imu_t_s, session.imu_w_rad_s, session.odo_t_s, session.odo_distance_m,
                     align, meta.latitude_rad, meta.height_m, misalign, config.block_size,
                     progress=within("dead reckoning", 0.02, 0.2))

    order = np.argsort(session.fixes.t_s, kind="stable")
    fix_t = session.fixes.t_s[order]
    fix_pt = np.asarray(session.fixes.point, dtype=object)[order]
    fix_enh = session.fixes.enh_m[order]
    origin = fix_enh[0].copy()
    # the filter works in a local true-north ground frame (the dead reckoning's); a projected
    # grid is turned by its convergence and scaled by its combined scale factor about the first fix
    fix_ned = grid_to_ned(fix_enh, origin, grid)
    fix_blocks = np.clip(np.searchsorted(dr.t_s, fix_t), 0, dr.t_s.shape[0] - 1)

    if align.heading_source == "fixes":
        report("dead reckoning with the heading from the fixes", 0.2)
        align, dr = _heading_from_fixes(session, align, dr, fix_blocks, fix_ned, lever, misalign, config)
    levelled_t, stop_roll = np.empty(0), None
    if config.level_at_stops:
        report("levelling at the stops", 0.22)
        stop_roll, _ = stop_levels(session.imu_t_s, session.imu_f_m_s2, session.odo_t_s,
                                   session.odo_distance_m, fix_t, misalign, w_rad_s=session.imu_w_rad_s)
        dr = with_roll_levelled(dr, fix_t, stop_roll)
        levelled_t = levelled_stop_times(dr, fix_t, stop_roll)
    if not config.level_at_stops or levelled_t.size == 0:
        levelled_t = dr.t_s[:1]  # the static alignment's level, held from the start

    nodes = filter_nodes(dr, fix_blocks, config.node_spacing_m, config.max_node_dt_s)
    handling = handling_blocks(dr)
    fix_nodes = np.searchsorted(nodes, fix_blocks)
    noise = filter_noise(session.meta, config)
    P0, heading_sigma = initial_covariance(session.meta, align, align.t_end_s - session.imu_t_s[0], config)
    scale = state_scale(P0)
    R = fix_covariances(session.fixes.covariance_enh_m2()[order], grid)
    forced = np.array([p in set(config.force_accept) for p in fix_pt], dtype=bool)
    if config.smoother not in ("rts", "tfs", "none"):
        raise ValueError(f"unknown smoother {config.smoother!r}: use rts, tfs or none")

    # Relinearisation (Gauss-Newton on the dead reckoning): the error model is linear in the
    # attitude errors, the dead reckoning is not (a 1 deg heading error shortens 60 m by 9 mm).
    # Each pass corrects the original dead reckoning with the current estimate of the attitude and
    # scale errors, exactly (finite rotations), and filters again with the fixes' innovations
    # against that corrected trajectory, expressed back in terms of the total error so that a
    # linear problem would give the same answer in every pass.
    correction = np.zeros((dr.t_s.shape[0], 8))
    dr_cur = dr
    # the linearisation point must follow the error dynamics: only a smoothed estimate does
    passes = 1 if config.smoother == "none" else config.relinearisations + 1
    # every pass's smoothed track tests each fix against all the others (data snooping); a pass
    # more, up to SNOOPING_PASSES, when that changes a verdict
    snoop = config.gate_probability is not None and config.smoother != "none"
    share = 0.6 / (passes + snoop)  # of the run, for each pass: error model, filter and smoother
    # the snooping's statistics: the last, and the one on which a fix was last moved
    snoop_stat = np.full(len(fix_t), np.nan)
    moved_stat = np.full(len(fix_t), np.nan)
    snoop_passes = 0
    xs_prev = F_prev = None
    it = -1
    while True:
        it += 1
        base = 0.25 + it * share
        label = f"pass {it + 1} of {passes}"
        report(f"error model, {label}", base)
        lever_ned = dr_cur.trolley_to_nav[fix_blocks].apply(lever)
        p0 = fix_ned[0] - lever_ned[0] - dr_cur.position_ned_m[fix_blocks[0]]
        F, Q = error_model(dr_cur, nodes, noise, *turn_sigmas(meta, config), handling=handling)
        if F_prev is not None:
            # the correction's positions integrate its attitude and scale errors along the previous
            # pass's headings (its smoother's model); this pass's model integrates the total error
            # along the corrected ones. Re-integrated along these, the correction's positions
            # follow this pass's model, as the total error does: kept as they were, the two
            # models differ by speed x heading correction x the correction itself, the second
            # order of the heading error (MEMS: 3.7 deg, ~20 mm along the track per 60 m, and
            # the relinearised pass's forward NIS grew to 25-322 on correct fixes)
            xs_prev = xs_prev.copy()
            xs_prev[1:, _POS] += np.cumsum(np.einsum("kij,kj->ki", (F - F_prev)[:, _POS, :], xs_prev[:-1]), axis=0)
            correction = correction.copy()
            correction[:, _POS] = _interp_nodes(dr, nodes, xs_prev[:, _POS])
        offset = correction[:, _POS] - correction[fix_blocks[0], _POS]
        H = fix_matrices(lever_ned, dr_cur.euler_rad()[fix_blocks, 2])
        # the lever arm was put into the frame with the corrected attitude: its error in terms of
        # the total attitude error adds back the correction's share
        att = [_IDX_HEADING, _IDX_PITCH]
        lever_offset = np.einsum("mik,mk->mi", H[:, :, att], correction[fix_blocks][:, att])
        z = p0 + dr_cur.position_ned_m[fix_blocks] + lever_ned - fix_ned + offset[fix_blocks] + lever_offset
        meas = meas_all = Measurements(fix_nodes, z, H, R)
        fwd_progress = within(f"forward filter, {label}", base + 0.1 * share, base + 0.55 * share)
        if it == 0:
            fwd = forward_filter(F, Q, np.zeros(8), P0, meas, gate_probability=config.gate_probability,
                                 force_accept=forced, progress=fwd_progress)
            gated = fwd  # the gate decides here; the snooping below may change its verdicts
            gate_accepted = fwd.accepted.copy()
        else:
            kept = meas.subset(gated.accepted)
            fwd = forward_filter(F, Q, np.zeros(8), P0, kept, gate_probability=None, progress=fwd_progress)
            meas = kept
            fwd.accepted = np.ones(len(kept), dtype=bool)
        sm_progress = within(f"{config.smoother} smoother, {label}", base + 0.55 * share, base + share)
        if config.smoother == "rts":
            sm = rts_smooth(F, Q, fwd, scale=scale, progress=sm_progress)
            xs, Ps = sm.x, sm.P
        elif config.smoother == "tfs":
            sm = two_filter_smooth(F, Q, meas.subset(fwd.accepted), fwd, scale=scale, progress=sm_progress)
            xs, Ps = sm.x, sm.P
        else:
            xs, Ps = fwd.x_post, fwd.P_post
        snooped = False
        if snoop:
            # the forward gate judges a fix by the ones before it; here each is judged by all the
            # others (a wrong fix the gate took, a right one rejected after it)
            res = snooped_verdicts(F, Q, np.zeros(8), P0, meas_all, gated.accepted, config.gate_probability,
                                   force_accept=forced, scale=scale, smoothed=SmoothedResult(xs, Ps))
            snoop_stat = res.statistic
            moved = res.removed | res.added
            if moved.any() and snoop_passes < SNOOPING_PASSES:
                snooped = True
                snoop_passes += 1
                moved_stat[moved] = res.moved_statistic[moved]
                gated.accepted = res.accepted
                passes = max(passes, it + 2)
        x_blocks = _interp_nodes(dr, nodes, xs)
        ned = p0 + dr_cur.position_ned_m - (x_blocks[:, _POS] - offset)
        dr_used = dr_cur
        correction = x_blocks
        xs_prev, F_prev = xs, F
        worst_angle = float(np.max(np.abs(x_blocks[:, [3, 6]])))
        worst_scale = float(np.max(np.abs(x_blocks[:, 2])))
        if not snooped and (it >= passes - 1 or (worst_angle < config.relinearise_above_rad and worst_scale < 1e-3)):
            break  # the dead reckoning is close enough to the truth for the linear model
        dr_cur = corrected_dead_reckoning(dr, correction)
        if stop_roll is not None:
            # the correction turns the attitude about the pitch axis of the dead-reckoned heading;
            # off the true one by the heading error, that turn tilts the roll the stops levelled
            # (MEMS: 3.8 deg x 16.5 mrad, 0.55 mrad of roll, 0.8 mm of cant): level it again
            dr_cur = with_roll_levelled(dr_cur, fix_t, stop_roll)

    # smoothed errors at every DR block, subtracted from the dead-reckoned trajectory
    Pdiag = np.diagonal(Ps, axis1=1, axis2=2)[:, _POS]
    var_blocks = _interp_nodes(dr, nodes, np.column_stack([Pdiag, Ps[:, _IDX_N, _IDX_E]]))
    enh = ned_to_grid(ned, origin, grid)
    vE, vN, cEN = horizontal_covariance_to_grid(var_blocks[:, 1], var_blocks[:, 0], var_blocks[:, 3], grid)
    sigma_enh = np.sqrt(np.maximum(np.column_stack([vE, vN, var_blocks[:, 2]]), 0.0))
    roll = dr_used.euler_rad()[:, 0]
    roll_sigma = np.sqrt(level_sigma_rad(align, config) ** 2 + em.levelled_roll_variance(
        dr.t_s, levelled_t, imu.gyro_arw_rad_sqrt_s, noise.gyro_bias_rw_rad_s_sqrt_s, imu.gyro_bias_sigma_rad_s))
    traj = Trajectory(dr.t_s, dr.travel_m, enh, sigma_enh, roll, x_blocks, odometer_m=dr.distance_m,
                      cov_EN_m2=cEN, roll_sigma_rad=roll_sigma)

    # innovation: the DR error the fix saw minus the error the filter predicted, in grid E, N, H
    # (of the first pass, the one that gated the fixes)
    fwd = gated
    y = fwd.innovation
    innov_enh = np.column_stack([y[:, 1], y[:, 0], -y[:, 2]])
    if grid is not None:
        innov_enh = grid.local_to_grid(innov_enh)
    # on the forward gate's verdicts: fixes turned against north agree with one another, and the
    # snooping would take them back (the track turned with them, the cause unsaid)
    check_rotation(dr, fix_blocks, fix_ned, lever, gate_accepted, heading_sigma, grid)
    reasons = []
    thr = None
    if config.gate_probability is not None:
        thr = gate_threshold(config.gate_probability, 3)
        out_thr = gate_threshold(SNOOP_OUT_PROBABILITY, 3)
    for j, (acc, nis_j, f) in enumerate(zip(fwd.accepted, fwd.nis, forced)):
        gate = f"innovation NIS {nis_j:.1f} > {thr:.1f}" if thr is not None else ""
        # the statistic on which the snooping moved the fix; else the last one
        stat = moved_stat[j] if np.isfinite(moved_stat[j]) else snoop_stat[j]
        others = f"NIS {stat:.1f} against the smoothed track of the other fixes"
        if acc and not gate_accepted[j]:
            reasons.append(f"taken back: {gate} at the forward gate, {others} (data snooping)")
        elif not acc and gate_accepted[j]:
            why = (f"> {out_thr:.1f} (data snooping, p={SNOOP_OUT_PROBABILITY})" if stat > out_thr else
                   f"> {thr:.1f}, and without it rejected fixes agree again (data snooping)")
            reasons.append(f"rejected: {others} {why}; the forward gate took it at NIS {nis_j:.1f}")
        elif acc:
            reasons.append("accepted by the crew despite the gate" if f and thr is not None and nis_j > thr else "")
        else:
            reasons.append(f"{gate} (chi-square gate, 3 dof, p={config.gate_probability})"
                           + (f"; {others}" if np.isfinite(stat) else ""))
    fixes = FixReport(fix_t, fix_pt, fix_enh, innov_enh, fwd.nis, fwd.accepted, reasons)

    report("stations", 0.85)
    stations = make_stations(traj, session, design, config, level_sigma_rad(align, config))
    ranks = None
    if with_observability:
        report("observability", 0.95)
        ranks = session_observability_ranks(dr, fix_blocks[fwd.accepted], config.node_spacing_m)
    acc = fwd.accepted
    summary = {
        "fixes_used": int(acc.sum()),
        "fixes_rejected": int((~acc).sum()),
        # the most fixes rejected one after another (from 3 on, warned about): runs of fixes
        # that agree with one another are taken back, so these disagree among themselves too
        "longest_rejected_run": longest_run(~acc),
        # rejected by the gate, taken back by the snooping (they agree with the other fixes)
        "fixes_readmitted": int((acc & ~gate_accepted).sum()),
        # taken by the forward gate, rejected against the smoothed track of the other fixes
        "fixes_snooped_out": int((~acc & gate_accepted).sum()),
        # the first fix anchors the dead reckoning (its innovation is zero by construction)
        "rms_innovation_m": (float(np.sqrt(np.mean(innov_enh[1:][acc[1:]] ** 2))) if acc[1:].any()
                             else float("nan")),
        "max_sigma_m": float(np.nanmax(np.column_stack([stations.sigma_E_m, stations.sigma_N_m,
                                                        stations.sigma_H_m]))) if len(stations.chainage_m) else float("nan"),
        "heading_source": align.heading_source,
        "initial_heading_deg": float(np.rad2deg(align.heading_rad)),
        "heading_sigma_deg": float(np.rad2deg(heading_sigma)),
        "nodes": int(len(nodes)),
        "observability_ranks": list(ranks) if ranks is not None else None,
        # the project grid at the site (trolley.projection); None without a CRS
        "crs": meta.crs,
        "vertical_datum": meta.vertical_datum,
        "grid_convergence_deg": float(np.rad2deg(grid.convergence_rad)) if grid is not None else None,
        "grid_scale_factor": grid.point_scale if grid is not None else None,
        "grid_combined_scale": grid.combined_scale if grid is not None else None,
    }
    report("done", 1.0)
    return ProcessResult(stations, traj, fixes, align, dr, ranks, config, int(len(nodes)), summary)


def session_observability_ranks(dr: DeadReckoning, fix_blocks: np.ndarray, min_travel_m: float
                                ) -> tuple[int, int]:
    """Observability ranks of the session's own error models between its fixes (Jiang 2017 Eq. 26).

    The fixes are grouped into stops (fixes less than ``min_travel_m`` of odometer travel apart
    were taken at one stop); between consecutive stops the models of Eq. 19 and 24 are formed at
    that interval's mean odometer speed and mean north and east velocity of the dead reckoning,
    and :func:`trolley.error_models.interval_observability_ranks` returns the smallest ranks.
    With fixes at a single stop, the whole session is one interval. A trolley that moves less
    than ``min_travel_m`` in an interval counts as standing (v = 0): the dead reckoning of a
    standing trolley jitters by micrometres, which would make any rank full numerically.

    Parameters
    ----------
    dr : the dead reckoning.
    fix_blocks : DR block index of every accepted fix.
    min_travel_m : shortest travel that counts as motion (the node spacing).

    Returns
    -------
    (vertical rank, level rank): 3 and 5 when every interval observes all states.
    """
    b = np.sort(np.asarray(fix_blocks, dtype=int))
    if b.size == 0:
        b = np.array([0])
    travel = dr.travel_m
    d = travel[b]
    stops = b[np.concatenate([[True], np.diff(d) > min_travel_m])]
    if stops.size < 2:
        stops = np.array([0, dr.t_s.shape[0] - 1])
    dt, speed, vn, ve = interval_motion(dr, stops)
    moving = (np.diff(travel[stops]) > min_travel_m) & (dt > 0)
    return em.interval_observability_ranks(np.where(moving, speed, 0.0), np.where(moving, vn, 0.0),
                                           np.where(moving, ve, 0.0))


def corrected_dead_reckoning(dr: DeadReckoning, error_states: np.ndarray) -> DeadReckoning:
    """The dead reckoning corrected with estimated attitude and odometer-scale errors.

    With ``C_est = (I - [phi x]) C_true`` (Jiang 2017 Eq. 8) the true attitude is
    ``exp([phi x]) C_est``, and with Eq. 11 the true distance is ``ds_est / (1 + dk)``. The
    equivalent pitch and heading errors of the states become the navigation-frame vector
    ``phi = [-sin(psi) phi_pitch, cos(psi) phi_pitch, phi_D]`` (Eq. 4, roll error unobservable
    and taken as zero); each position increment is rotated and scaled exactly.

    Parameters
    ----------
    dr : the original dead reckoning.
    error_states : (K, 8) error estimate at every block (order ``STATE_NAMES``).
    """
    from scipy.spatial.transform import Rotation

    psi = dr.euler_rad()[:, 2]
    phi = np.column_stack([-np.sin(psi) * error_states[:, 6], np.cos(psi) * error_states[:, 6],
                           error_states[:, 3]])
    rot = Rotation.from_rotvec(phi)
    mid = 0.5 * (phi[1:] + phi[:-1])
    dk = 0.5 * (error_states[1:, 2] + error_states[:-1, 2])
    inc = Rotation.from_rotvec(mid).apply(np.diff(dr.position_ned_m, axis=0)) / (1.0 + dk)[:, None]
    pos = np.zeros_like(dr.position_ned_m)
    np.cumsum(inc, axis=0, out=pos[1:])
    return DeadReckoning(t_s=dr.t_s, distance_m=dr.distance_m, trolley_to_nav=Rotation.from_quat(quat_multiply(rot.as_quat(), dr.trolley_to_nav.as_quat())),
                         position_ned_m=pos)


def _heading_from_fixes(session, align, dr, fix_blocks, fix_ned, lever, misalign, config):
    """Heading for gyros that cannot gyrocompass: turn the DR so that it joins two distant fixes."""
    from scipy.spatial.transform import Rotation

    pos = dr.position_ned_m[fix_blocks] + dr.trolley_to_nav[fix_blocks].apply(lever)
    meas_d = fix_ned - fix_ned[0]
    dr_d = pos - pos[0]
    far = np.flatnonzero(np.hypot(meas_d[:, 0], meas_d[:, 1]) > 10.0)
    if far.size == 0:
        raise ValueError("the IMU cannot gyrocompass, session.toml gives no initial_heading_deg, and no "
                         "two fixes are 10 m apart to take the heading from")
    j = far[0]
    dpsi = np.arctan2(meas_d[j, 1], meas_d[j, 0]) - np.arctan2(dr_d[j, 1], dr_d[j, 0])
    C = Rotation.from_euler("z", dpsi) * align.imu_to_nav
    dist = float(np.hypot(meas_d[j, 0], meas_d[j, 1]))
    # The chord fixes the dead reckoning's heading averaged along the leg, not the heading at
    # the start of the dead reckoning: the gyro bias and angle random walk turn it by
    # bias x dt and arw x sqrt(dt) in the time dt from there to half-way along the chord. The
    # filter's P0 takes heading and bias as independent, so that drift belongs in the sigma
    # (without it a MEMS unit gave 2.4 x its sigmas laterally, and rejected good fixes).
    travel = dr.travel_m
    half = np.searchsorted(travel, 0.5 * (travel[fix_blocks[0]] + travel[fix_blocks[j]]))
    dt = max(float(dr.t_s[min(half, dr.t_s.shape[0] - 1)] - dr.t_s[0]), 0.0)
    imu = session.meta.imu
    sig = float(np.sqrt((np.sqrt(2.0) * max(session.meta.fix_sigma_m, 1e-4) / dist) ** 2
                        + (imu.gyro_bias_sigma_rad_s * dt) ** 2 + imu.gyro_arw_rad_sqrt_s ** 2 * dt))
    ypr = (C * mounting_rotation(misalign).inv()).as_euler("ZYX")
    new = StaticAlignment(C, float(ypr[2]), float(ypr[1]), float(ypr[0]), align.level_sigma_rad,
                          max(sig, np.deg2rad(0.01)), "fixes", align.t_end_s)
    m = session.meta
    return new, dead_reckon(session.imu_t_s, session.imu_w_rad_s, session.odo_t_s, session.odo_distance_m,
                            new, m.latitude_rad, m.height_m, misalign, config.block_size)


def _facing(chainage_m: np.ndarray, odometer_m: np.ndarray) -> np.ndarray:
    """+1 where the trolley's x axis points to increasing chainage, -1 where it is turned around.

    Judged from the motion: the odometer counts up when the trolley moves along its own x axis,
    so the signs of the chainage and odometer steps agree when it faces increasing chainage.
    Standing samples take the facing of the last motion (of the first, before any).
    """
    step = np.sign(np.diff(chainage_m) * np.diff(odometer_m))
    facing = np.concatenate([[0.0], step])
    known = np.flatnonzero(facing != 0)
    if known.size == 0:
        return np.ones(chainage_m.shape[0])
    last = np.maximum.accumulate(np.where(facing != 0, np.arange(facing.size), 0))
    out = facing[last]
    out[:known[0]] = facing[known[0]]
    return out


def make_stations(traj: Trajectory, session: RawSession, design, config: ProcessConfig,
                  level_sigma: float = float("nan")) -> Stations:
    """Resample the corrected trajectory on a fixed chainage step (FORMATS.md section 2).

    The cant's 1-sigma comes from ``traj.roll_sigma_rad``, or, where the trajectory has none (the
    live filter's), from ``level_sigma`` (rad, :func:`level_sigma_rad`); NaN leaves it unknown.
    """
    enh = traj.enh_m
    if design is not None:
        # chainage is smooth in the odometer distance: project every metre and interpolate (on the
        # 10 km benchmark against every 0.25 m: stations moved along the track by up to 14 um,
        # their deviations from the design by 3 nm)
        d = traj.distance_m
        idx = np.unique(np.concatenate([[0, d.size - 1], np.searchsorted(d, np.arange(d[0], d[-1], 1.0))]))
        idx = idx[np.concatenate([[True], np.diff(d[idx]) > 0])]
        proj = design.project(enh[idx, 0], enh[idx, 1], enh[idx, 2])
        ch = np.interp(d, d[idx], np.asarray(proj.chainage_m, dtype=float))
    else:
        seg = np.linalg.norm(np.diff(enh, axis=0), axis=1)
        ch = np.concatenate([[0.0], np.cumsum(seg)])
    # the chainage runs one way along the survey; keep samples where it strictly advances
    sign = 1.0 if ch[-1] >= ch[0] else -1.0
    run = np.maximum.accumulate(sign * ch)
    keep = np.concatenate([[True], np.diff(run) > 1e-9])
    keep &= sign * ch >= run - 1e-9
    c = sign * ch[keep]
    if c.size < 2:
        empty = np.array([])
        return Stations(**{k: empty for k in _STATION_FIELDS})
    step = config.step_m
    # a grid station a few mm beyond either end is kept: the projected start of a run that
    # begins at chainage 0 lands at 0.0004 m and would otherwise drop the station at 0
    tol = STATION_END_TOLERANCE_M
    s = np.arange(np.ceil((c[0] - tol) / step) * step, c[-1] + tol + 1e-12, step)
    s = s[(s >= c[0] - tol) & (s <= c[-1] + tol)] + 0.0  # + 0.0: no "-0.000" station

    def at(y):
        # linear within the trajectory, extended along the end segments for those few mm
        yk = y[keep]
        out = np.interp(s, c, yk)
        lo, hi = s < c[0], s > c[-1]
        out[lo] = yk[0] + (s[lo] - c[0]) * (yk[1] - yk[0]) / (c[1] - c[0])
        out[hi] = yk[-1] + (s[hi] - c[-1]) * (yk[-1] - yk[-2]) / (c[-1] - c[-2])
        return out

    E, N, Hh = at(enh[:, 0]), at(enh[:, 1]), at(enh[:, 2])
    sE, sN, sH = (at(traj.sigma_enh_m[:, i]) for i in range(3))
    cEN = at(traj.cov_EN_m2) if traj.cov_EN_m2 is not None else np.zeros_like(sE)
    # interpolated apart, the covariance could step past the sigmas' product by rounding
    cEN = np.clip(cEN, -sE * sN, sE * sN)
    t = at(traj.t_s)
    # cant from the roll of a trolley that faces increasing chainage; turned around, its roll is
    # the opposite of the track's (FORMATS.md 2: cant > 0 when the left rail is higher)
    facing = np.ones(enh.shape[0])
    if traj.odometer_m is not None:
        facing = _facing(ch, np.asarray(traj.odometer_m, dtype=float))
    rail = session.meta.trolley.rail_spacing_m
    cant = at(facing * rail * np.sin(traj.roll_rad))
    twist = cant - np.interp(s - config.twist_base_m, s, cant, left=np.nan)
    # d(rail sin roll) = rail cos(roll) d(roll); the roll's sigma grows between the levelled stops
    roll_sigma = at(traj.roll_sigma_rad) if traj.roll_sigma_rad is not None else level_sigma
    sigma_cant = rail * np.sqrt(np.clip(1.0 - (cant / rail) ** 2, 0.0, 1.0)) * roll_sigma
    if session.gauge_t_s is not None and len(session.gauge_t_s) > 1:
        gt = np.asarray(session.gauge_t_s, dtype=float)
        gauge = np.interp(t, gt, session.gauge_m, left=np.nan, right=np.nan)
        # a gauge is measured, never bridged: no value where the sensor was silent (a gap of more
        # than five of its sample intervals, at least 1 s), e.g. unplugged for a while
        dt = np.diff(gt)
        gap = np.maximum(5.0 * float(np.median(dt)), 1.0)
        j = np.clip(np.searchsorted(gt, t, side="right") - 1, 0, dt.size - 1)
        gauge[dt[j] > gap] = np.nan
    else:
        gauge = np.full_like(s, np.nan)
    chain = sign * s
    if design is not None:
        p = design.project(E, N, Hh)
        lat = np.asarray(p.lateral_m, dtype=float)
        vert = np.asarray(p.vertical_m, dtype=float)
    else:
        lat = np.full_like(s, np.nan)
        vert = np.full_like(s, np.nan)
    order = np.argsort(chain, kind="stable")
    cols = [chain, E, N, Hh, sE, sN, sH, lat, vert, gauge, cant, twist, t, cEN, sigma_cant]
    return Stations(**{k: np.asarray(x)[order] for k, x in zip(_STATION_FIELDS, cols)})
