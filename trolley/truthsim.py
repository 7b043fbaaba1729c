"""Truth simulator: a full 3-D trolley survey (stop-and-go) with strapdown IMU synthesis.

This is the validation model of the project, deliberately NOT the filters' reduced-order model
(Jiang 2017 Sec. 3 linearises; the truth here does not):

1. Track truth (chainage domain). The design alignment (straights, clothoids, arcs, grades,
   parabolic vertical curves, cant) plus four independent mm-level random irregularities:
   lateral (horizontal, + to the right of increasing chainage), vertical (+ up), cross-level
   (rail height difference added to the cant, + left rail higher) and gauge. Each is a Gaussian
   process with the one-sided spatial PSD

       S(nu) = A * nu^-2 * (nu/nu_lo)^4 / (1 + (nu/nu_lo)^4) * 1 / (1 + (nu/nu_hi)^8),
       nu_lo = 1/200 m^-1, nu_hi = 1/3 m^-1,

   i.e. the classic nu^-2 displacement spectrum of track geometry, band-limited to wavelengths
   of about 3-200 m by a 2nd-order high-pass and a 4th-order low-pass; each realisation is
   scaled so that its RMS over the surveyed stretch equals ``irregularity_rms_m``. The reference
   point path P(s) = design(s) + lateral(s) * right(s) + vertical(s) * up and the roll
   arcsin(sin(cant(s)) + crosslevel(s) / rail_spacing) are sampled every 0.05 m and represented
   by quintic interpolating splines, which ARE the truth (positions, attitude, rates and
   accelerations are all derived from the same splines, so they are mutually consistent).
2. Trolley attitude w.r.t. local-level NED (FORMATS.md sec. 1): yaw = bearing of the 3-D
   tangent dP/ds, pitch = its elevation angle, roll = the track roll; ZYX Euler angles,
   C_bt^n = Rz(yaw) Ry(pitch) Rx(roll). The trolley x axis is the path tangent, so its velocity
   in the trolley frame is [v, 0, 0] exactly (the non-holonomic odometer model of Jiang 2017
   Eq. 7).
3. Stop-and-go motion s(t): static alignment of ``static_s`` at the first stop, then legs of
   ``fix_spacing_m`` with a raised-cosine acceleration a(t) = a_p sin^2(pi t / T_a) up to
   ``speed_m_s`` (acceleration and jerk continuous), cruise, mirrored deceleration, and a stop of
   ``stop_s`` at each stop chainage (and at the end), where the total station measures the
   prism (one or more fixes at the middle of each stop, the first during the static alignment).
4. Strapdown synthesis (Jiang 2017 Sec. 3.1, Eq. 1): each IMU row at t_k holds the MEAN angular
   rate and specific force over (t_{k-1}, t_k], as strapdown IMUs output increments/dt:
   w_ib^b = C_n^b (w_ie^n + w_en^n) + w_nb^b, with w_nb^b = Log(C(t_{k-1})^T C(t_k)) / dt taken
   exactly from consecutive attitude quaternions, Earth rate w_ie^n = W [cos L, 0, -sin L] and
   transport rate w_en^n = [v_E, -v_N, -v_E tan L] / (R + h); f^b = C_n^b (a^n + (2 w_ie^n +
   w_en^n) x v^n - g^n) with g^n = [0, 0, normal gravity(L, h)], a^n = P'' sdot^2 + P' sddot the
   acceleration of the reference point (centripetal included); both evaluated at the interval
   midpoint. The latitude follows the path, L = L0 + (N - N0) / (R + h). Without a CRS the grid
   is taken as a local tangent map: grid north = true north, grid scale 1 (documented in
   docs/simulator.md). With ``crs`` the design and the CPIII are in that projected grid and the
   truth moves in a local true-north ground frame: the design's grid offsets from the first stop
   are turned by the grid convergence gamma and divided by the combined scale k R / (R + h)
   (``trolley.projection``, both taken at the centroid of the stops, as the engine takes them
   at the centroid of the fixes), so the IMU sees true headings and
   the odometer ground distances, while the fixes, truth.csv and the chainage stay in the grid.
   The IMU sits at the reference point with mounting C_b^bt = Rz Ry Rx(nominal + residual)
   (Jiang 2017 Eq. 10: C_bt^b = I - [eps x] for small angles), the residual being a seeded
   N(0, imu_residual_misalignment_rad) per axis that the processing does not know.
5. Sensor errors: gyro turn-on bias N(0, BI), first-order Gauss-Markov bias instability
   (correlation time ``gyro_correlation_time_s``, stationary sigma BI), angle random walk
   (white rate noise ARW / sqrt(dt)), scale factor N(0, sf); accelerometer bias N(0, b_a) and
   white noise VRW / sqrt(dt); odometer (Jiang 2017 Eq. 11): scale error dk0 ~ N(0, scale_error)
   plus the random walk dk with PSD root ``scale_noise_per_sqrt_s``, applied to the increments
   of the 3-D path length of the reference point, then encoder quantisation (floor to
   ``resolution_m``); total station: N(0, fix_sigma_m) per grid axis on the prism position
   P + C_bt^n @ prism_lever_arm (NED -> ENH); gauge sensor: N(0, gauge_sigma_m) at
   ``gauge_rate_hz``.

Everything is vectorised (the time axis is processed in chunks of about a million samples to
bound memory); a 10 km survey at 200 Hz (~3 M IMU samples) simulates in seconds.

References
----------
Jiang, Q., Wu, W., Jiang, M., Li, Y. (2017). A new filtering and smoothing algorithm for railway
track surveying based on landmark and IMU/odometer. Sensors 17(6), 1438. Sec. 2-3, Eq. 1, 7, 10, 11.
Munoz, S., et al. (2021): validation against a model richer than the estimator's.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline

from trolley import units
from trolley.earth import (EARTH_RADIUS_M, earth_rate_n, normal_gravity_m_s2,
                           transport_rate_n)
from trolley.projection import GridFactors, site_factors
from trolley.sensors import IMU_PRESETS, ImuFigures, OdometerFigures
from trolley.session import Fixes, RawSession, SessionMeta, TrolleyGeometry

__all__ = [
    "SimulationConfig",
    "TruthTrack",
    "TruthProfile",
    "TruthGeometry",
    "MotionProfile",
    "SimulatedSurvey",
    "simulate_survey",
    "truth_geometry",
    "motion_profile",
    "irregularity_psd",
    "quat_from_euler",
]

#: Knot spacing of the truth splines, m (60+ knots per shortest irregularity wavelength).
TRUTH_GRID_STEP_M = 0.05
#: Irregularity band edges (wavelengths), m.
IRREGULARITY_LONGEST_M = 200.0
IRREGULARITY_SHORTEST_M = 3.0
#: IMU samples per processing chunk (bounds memory: ~1 GB peak for 10 km at 200 Hz otherwise).
_CHUNK = 1 << 19


@dataclass(frozen=True)
class SimulationConfig:
    """Settings of one simulated survey (SI units).

    Attributes
    ----------
    length_m : surveyed length along the chainage, m.
    start_chainage_m : chainage of the first stop; None = start of the alignment.
    fix_spacing_m : distance between stops (CPIII pairs), m.
    stop_s : standstill at each stop, s.
    static_s : initial static alignment at the first stop, s.
    speed_m_s : cruise speed, m/s.
    accel_time_s : duration of the raised-cosine acceleration (and deceleration), s.
    imu_rate_hz, odometer_rate_hz, gauge_rate_hz : sample rates, Hz.
    imu, odometer : sensor figures the errors are drawn from (also written to session.toml).
    fix_sigma_m : total-station 1-sigma per axis, m. gauge_sigma_m : gauge sensor 1-sigma, m.
    irregularity_rms_m : RMS of each of the four track irregularities, m (0: design only).
    latitude_rad, height_m : site (session.toml [site]); the latitude is that of the first stop.
    trolley : trolley geometry (prism lever arm, nominal IMU misalignment, rail spacing, gauge).
    imu_residual_misalignment_rad : 1-sigma per axis of the unknown mounting residual, rad.
    gyro_correlation_time_s : correlation time of the Gauss-Markov bias instability, s.
    fixes_per_stop : total-station measurements per stop (spread over the stop).
    turn_at_stops : indices of the stops (1 = the first stop after the static alignment) at
        which the crew turns the trolley around: it is lifted, turned by 180 deg about the track
        normal through the reference point within ``turn_s`` at the middle of the stop, and put
        back; from then on it runs backwards in its own frame (the odometer counts down) while
        the chainage keeps increasing. Such a stop has ``fixes_per_stop`` fixes before the turn
        and as many after it.
    turn_s : duration of a turn, s (the stop must be at least ``turn_s + 4`` s long).
    lift_at_stops : stops at which the crew lifts the trolley off the track (a train passes) and
        puts it back, the same way round, within ``turn_s``: tilted by up to ``lift_tilt_rad``
        about its x axis while carried. Fixes before and after, as for a turn.
    lift_tilt_rad : largest tilt while the trolley is carried, rad.
    placement_offset_m : a lifted or turned trolley is put back this far further along the track
        (the odometer does not count it; the next leg is that much shorter).
    errors : False switches every sensor error off (biases, noise, scale factors, residual
        misalignment, quantisation stays); the track irregularities are kept.
    initial_heading : write ``initial_heading_deg`` (the true trolley yaw at the start) to the
        session; None = only when the IMU preset cannot gyrocompass.
    crs : project CRS of the design's grid (EPSG code, PROJ string), or None for a local
        true-north, ground-scale grid. With it the site latitude is the CRS's at the stops' centroid
        (``latitude_rad`` is ignored) and session.toml carries ``[site] crs`` unless
        ``crs_in_session`` is False (a crew that forgot to give it).
    crs_in_session : write the CRS to the session metadata.
    seed : seed of ``np.random.default_rng``.
    track_seed : seed of the track irregularities alone, or None to draw them with ``seed``. Two
        surveys with one ``track_seed`` and two ``seed``s are two surveys of one track (a repeat
        run: the same rails, their own sensor errors, fixes and station setups).
    """

    length_m: float = 1200.0
    start_chainage_m: float | None = None
    fix_spacing_m: float = 60.0
    stop_s: float = 30.0
    static_s: float = 120.0
    speed_m_s: float = 1.0
    accel_time_s: float = 4.0
    imu_rate_hz: float = 200.0
    odometer_rate_hz: float = 100.0
    gauge_rate_hz: float = 10.0
    imu: ImuFigures = IMU_PRESETS["rlg"]
    odometer: OdometerFigures = field(default_factory=OdometerFigures)
    fix_sigma_m: float = 0.0006
    gauge_sigma_m: float = 1e-4
    irregularity_rms_m: float = 0.0005
    latitude_rad: float = float(units.deg_to_rad(28.0))
    height_m: float = 50.0
    trolley: TrolleyGeometry = field(default_factory=TrolleyGeometry)
    imu_residual_misalignment_rad: float = float(units.deg_to_rad(0.003))
    gyro_correlation_time_s: float = 1000.0
    fixes_per_stop: int = 1
    turn_at_stops: tuple[int, ...] = ()
    turn_s: float = 10.0
    lift_at_stops: tuple[int, ...] = ()
    lift_tilt_rad: float = 0.15
    placement_offset_m: float = 0.0
    errors: bool = True
    initial_heading: bool | None = None
    crs: str | None = None
    crs_in_session: bool = True
    seed: int = 0
    track_seed: int | None = None


# ------------------------------------------------------------------------------------------
# rotations (Hamilton quaternions [w, x, y, z], body -> navigation)
# ------------------------------------------------------------------------------------------
def quat_from_euler(roll, pitch, yaw) -> np.ndarray:
    """Quaternion of C = Rz(yaw) Ry(pitch) Rx(roll) (ZYX Euler angles, body -> nav).

    Returns
    -------
    ndarray (..., 4), [w, x, y, z].
    """
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    return np.stack([cr * cp * cy + sr * sp * sy,
                     sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy], axis=-1)


def euler_from_quat(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZYX Euler angles (roll, pitch, yaw in [0, 2 pi)) of [w, x, y, z] quaternions."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.mod(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)), 2.0 * np.pi)
    return roll, pitch, yaw


def handling_quat(motion, t) -> np.ndarray:
    """The trolley relative to the track frame while the crew handles it: turned about its z axis
    (the track normal), then tilted about its x axis while carried."""
    half = 0.5 * motion.turn_angle(t)
    tilt = 0.5 * motion.tilt(t)
    zero = np.zeros_like(half)
    qz = np.stack([np.cos(half), zero, zero, np.sin(half)], axis=-1)
    qx = np.stack([np.cos(tilt), np.sin(tilt), zero, zero], axis=-1)
    return _quat_mul(qz, qx)


def _quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack([pw * qw - px * qx - py * qy - pz * qz,
                     pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx,
                     pw * qz + px * qy - py * qx + pz * qw], axis=-1)


def _quat_conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """C(q) v (body -> nav) for stacks of quaternions and vectors."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def _rotvec_from_quat(q: np.ndarray) -> np.ndarray:
    q = np.where(q[..., :1] < 0.0, -q, q)
    u = q[..., 1:]
    n = np.linalg.norm(u, axis=-1)
    angle = 2.0 * np.arctan2(n, q[..., 0])
    small = n < 1e-12
    scale = np.where(small, 2.0 / q[..., 0], angle / np.where(small, 1.0, n))
    return u * scale[..., None]


def _dcm_from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


# ------------------------------------------------------------------------------------------
# track truth in the chainage domain
# ------------------------------------------------------------------------------------------
def irregularity_psd(nu_1_m) -> np.ndarray:
    """Shape of the one-sided irregularity PSD S(nu) (unscaled; see the module docstring).

    Parameters
    ----------
    nu_1_m : array_like, spatial frequency, cycles/m.

    Returns
    -------
    ndarray, S(nu) / A (m^2 per cycle/m, up to the scale A set by the RMS).
    """
    nu = np.asarray(nu_1_m, dtype=float)
    nu_lo, nu_hi = 1.0 / IRREGULARITY_LONGEST_M, 1.0 / IRREGULARITY_SHORTEST_M
    with np.errstate(divide="ignore", invalid="ignore"):
        x4 = (nu / nu_lo) ** 4
        s = nu ** -2.0 * x4 / (1.0 + x4) / (1.0 + (nu / nu_hi) ** 8)
    return np.where(nu > 0.0, s, 0.0)


def _irregularities(rng: np.random.Generator, n: int, step_m: float, rms_m: float,
                    survey: slice, count: int = 4) -> np.ndarray:
    """``count`` independent realisations on a grid, each scaled to ``rms_m`` over ``survey``."""
    if rms_m == 0.0:
        return np.zeros((n, count))
    nfft = 1 << int(np.ceil(np.log2(n + 4 * IRREGULARITY_LONGEST_M / step_m)))
    amp = np.sqrt(irregularity_psd(np.fft.rfftfreq(nfft, step_m)))
    spec = (rng.standard_normal((amp.size, count)) + 1j * rng.standard_normal((amp.size, count)))
    x = np.fft.irfft(spec * amp[:, None], n=nfft, axis=0)[:n]
    x *= rms_m / np.sqrt(np.mean(x[survey] ** 2, axis=0))
    return x


@dataclass
class TruthGeometry:
    """The true track as functions of the chainage s (quintic splines on a 0.05 m grid).

    Attributes
    ----------
    origin_E_m, origin_N_m : grid origin subtracted before fitting (keeps digits).
    position : spline of (E - E0, N - N0, H) of the track reference point.
    extras : spline of (roll_rad, gauge_m, lateral_m, vertical_m); lateral/vertical are the
        irregularities (truth minus design, + right / + up).
    arclength : spline of the 3-D path length from ``start_chainage_m``.
    start_chainage_m, end_chainage_m : the simulated stretch.
    rail_spacing_m : for cant = rail_spacing * sin(roll).
    grid : the projection at the site (``position`` is then in the local true-north ground
        frame, see :meth:`grid_enh`), or None (grid = local frame).
    """

    origin_E_m: float
    origin_N_m: float
    position: BSpline
    extras: BSpline
    arclength: BSpline
    start_chainage_m: float
    end_chainage_m: float
    rail_spacing_m: float
    grid: GridFactors | None = None

    def grid_enh(self, p) -> np.ndarray:
        """Grid E, N, H (..., 3) of positions (..., 3) in the frame of ``position``."""
        p = np.asarray(p, dtype=float)
        if self.grid is not None:
            p = self.grid.local_to_grid(p)
        return np.stack([p[..., 0] + self.origin_E_m, p[..., 1] + self.origin_N_m, p[..., 2]], axis=-1)

    def attitude(self, s, dp=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Trolley roll, pitch, yaw (ZYX, NED, yaw in [0, 2 pi)) at chainages ``s``."""
        if dp is None:
            dp = self.position(s, 1)
        yaw = np.mod(np.arctan2(dp[..., 0], dp[..., 1]), 2.0 * np.pi)
        pitch = np.arctan2(dp[..., 2], np.hypot(dp[..., 0], dp[..., 1]))
        roll = self.extras(s)[..., 0]
        return roll, pitch, yaw


def truth_geometry(alignment, start_chainage_m: float, length_m: float,
                   irregularity_rms_m: float, rail_spacing_m: float, nominal_gauge_m: float,
                   rng: np.random.Generator, step_m: float = TRUTH_GRID_STEP_M,
                   grid: GridFactors | None = None) -> TruthGeometry:
    """Design plus random irregularities, as splines of the chainage.

    Parameters
    ----------
    alignment : trolley.alignment.Alignment (anything with ``evaluate(s)``).
    start_chainage_m, length_m : stretch to simulate (a 5 m margin is added on both sides).
    irregularity_rms_m : RMS of each irregularity (lateral, vertical, cross-level, gauge), m.
    rail_spacing_m, nominal_gauge_m : trolley/track geometry.
    rng : random generator (the irregularities are drawn from it).
    step_m : knot spacing, m.
    grid : projection factors at the site: the positions are turned into the local true-north
        ground frame (module docstring, item 4); None keeps the grid.

    Returns
    -------
    TruthGeometry
    """
    margin = 5.0
    n_before = int(np.ceil(margin / step_m))
    n_survey = int(np.ceil(length_m / step_m))
    s = start_chainage_m + step_m * np.arange(-n_before, n_survey + 2 * n_before + 1)
    d = alignment.evaluate(s)
    irr = _irregularities(rng, s.size, step_m, irregularity_rms_m,
                          slice(n_before, n_before + n_survey + 1))
    lat, vert, xlevel, dgauge = irr.T
    heading = d.heading_rad
    e0, n0 = float(alignment.evaluate(np.array([start_chainage_m])).E_m[0]), \
        float(alignment.evaluate(np.array([start_chainage_m])).N_m[0])
    de = (d.E_m - e0) + lat * np.cos(heading)
    dn = (d.N_m - n0) - lat * np.sin(heading)
    h = d.H_m + vert
    if grid is not None:
        de, dn, h = grid.grid_to_local(np.column_stack([de, dn, h])).T
    sin_roll = np.sin(d.cant_rad) + xlevel / rail_spacing_m
    if np.any(np.abs(sin_roll) >= 1.0):
        raise ValueError("cant plus cross-level exceeds the rail spacing")
    roll = np.arcsin(sin_roll)
    position = make_interp_spline(s, np.column_stack([de, dn, h]), k=5)
    extras = make_interp_spline(s, np.column_stack([roll, nominal_gauge_m + dgauge, lat, vert]),
                                k=5)
    speed_factor = np.linalg.norm(position(s, 1), axis=1)
    arclength = make_interp_spline(s, speed_factor, k=5).antiderivative()
    offset = arclength(start_chainage_m)
    arclength = BSpline(arclength.t, arclength.c - offset, arclength.k)
    return TruthGeometry(origin_E_m=e0, origin_N_m=n0, position=position, extras=extras,
                         arclength=arclength, start_chainage_m=float(start_chainage_m),
                         end_chainage_m=float(start_chainage_m + length_m),
                         rail_spacing_m=float(rail_spacing_m), grid=grid)


# ------------------------------------------------------------------------------------------
# stop-and-go motion
# ------------------------------------------------------------------------------------------
@dataclass
class MotionProfile:
    """Stop-and-go chainage s(t) (vectorised, closed form).

    Attributes
    ----------
    stop_chainage_m : (m,) chainage of every stop (the first is the static alignment).
    stop_start_s, stop_end_s : (m,) standstill interval of every stop, s.
    leg_start_s, leg_duration_s, leg_speed_m_s : (m-1,) motion between stops.
    accel_time_s : raised-cosine acceleration time T_a.
    duration_s : end of the last stop.
    handling_start_s : (k,) start of every handling of the trolley by the crew (a turn or a lift,
        at the middle of a stop), s; ``turn_s`` long.
    handling_angle_rad : (k,) rotation about the trolley's z axis of each (pi: a turn, 0: a lift).
    handling_tilt_rad : (k,) largest tilt about the trolley's x axis while it is carried.
    handling_offset_m : (k,) along-track placement offset when it is put back.
    handling_stop : (k,) stop index of each.
    turn_s : duration of a handling, s.
    """

    stop_chainage_m: np.ndarray
    stop_start_s: np.ndarray
    stop_end_s: np.ndarray
    leg_start_s: np.ndarray
    leg_duration_s: np.ndarray
    leg_speed_m_s: np.ndarray
    accel_time_s: float
    duration_s: float
    handling_start_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    handling_angle_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    handling_tilt_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    handling_offset_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    handling_stop: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    turn_s: float = 10.0

    @property
    def turn_start_s(self) -> np.ndarray:
        """Start of every turn (a handling that turns the trolley around), s."""
        return self.handling_start_s[self.handling_angle_rad != 0.0]

    def _u(self, t_s) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        return np.clip((t[..., None] - self.handling_start_s) / self.turn_s, 0.0, 1.0)

    def turn_angle(self, t_s) -> np.ndarray:
        """Rotation of the trolley about its z axis relative to the track frame, rad.

        Each turn adds pi with the smooth step u - sin(2 pi u) / (2 pi), u = (t - t0) / turn_s,
        so the turn rate starts and ends at zero (no jump in the synthesised gyro output).
        """
        u = self._u(t_s)
        return np.sum(self.handling_angle_rad * (u - np.sin(2.0 * np.pi * u) / (2.0 * np.pi)), axis=-1)

    def tilt(self, t_s) -> np.ndarray:
        """Tilt of a carried trolley about its x axis, rad: ``tilt sin^2(pi u)`` during a lift."""
        u = self._u(t_s)
        return np.sum(self.handling_tilt_rad * np.sin(np.pi * u) ** 2, axis=-1)

    def handled(self, t_s) -> np.ndarray:
        """True while the crew holds the trolley off the track (its wheels do not turn)."""
        u = self._u(t_s)
        return np.any((u > 0.0) & (u < 1.0), axis=-1)

    def facing(self, t_s) -> np.ndarray:
        """+1 while the trolley faces increasing chainage, -1 while it is turned around
        (judged at the middle of a turn; the trolley only moves between turns)."""
        t = np.asarray(t_s, dtype=float)
        turned = self.handling_angle_rad != 0.0
        done = np.sum((t[..., None] >= self.handling_start_s + 0.5 * self.turn_s) & turned, axis=-1)
        return np.where(done % 2 == 0, 1.0, -1.0)

    def _placement(self, t, s, v, a):
        """The placement offsets: during a handling the trolley moves ``offset`` along the track
        (smooth step); on the next leg the offset shrinks to zero in proportion to the distance,
        so the trolley arrives at the planned stop."""
        for j in range(self.handling_start_s.size):  # a handful of handlings, not samples
            d = float(self.handling_offset_m[j])
            if d == 0.0:
                continue
            k = int(self.handling_stop[j])
            t0 = self.handling_start_s[j]
            T = self.turn_s
            during = (t > t0) & (t < t0 + T)
            u = (t[during] - t0) / T
            s[during] += d * (u - np.sin(2.0 * np.pi * u) / (2.0 * np.pi))
            v[during] += d * (1.0 - np.cos(2.0 * np.pi * u)) / T
            a[during] += d * 2.0 * np.pi * np.sin(2.0 * np.pi * u) / T ** 2
            s0 = self.stop_chainage_m[k]
            if k + 1 < self.stop_chainage_m.size:
                L = self.stop_chainage_m[k + 1] - s0
                after = (t >= t0 + T) & (t <= self.stop_start_s[k + 1])
                s[after] = s0 + d + (s[after] - s0) * (1.0 - d / L)
                v[after] *= 1.0 - d / L
                a[after] *= 1.0 - d / L
            else:
                s[t >= t0 + T] += d
        return s, v, a

    def evaluate(self, t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Chainage s, ds/dt and d2s/dt2 at times ``t_s`` (1-D array).

        Returns
        -------
        s_m, sdot_m_s, sddot_m_s2 : ndarrays.
        """
        t = np.asarray(t_s, dtype=float)
        s = np.empty(t.shape)
        v = np.zeros(t.shape)
        a = np.zeros(t.shape)
        leg = np.searchsorted(self.leg_start_s, t, side="right") - 1
        # standing: at the stop the last leg arrived at (or the first stop)
        stop = np.clip(leg + 1, 0, self.stop_chainage_m.size - 1)
        s[:] = self.stop_chainage_m[stop]
        legc = np.clip(leg, 0, max(self.leg_start_s.size - 1, 0))
        if self.leg_start_s.size == 0:
            return self._placement(t, s, v, a)
        tau = t - self.leg_start_s[legc]
        T = self.leg_duration_s[legc]
        moving = (leg >= 0) & (tau < T)
        if not np.any(moving):
            return self._placement(t, s, v, a)
        tau, T = tau[moving], T[moving]
        vc = self.leg_speed_m_s[legc[moving]]
        s_from = self.stop_chainage_m[legc[moving]]
        dist = self.stop_chainage_m[legc[moving] + 1] - s_from
        Ta = self.accel_time_s
        a_p = 2.0 * vc / Ta

        def ramp(u):
            x = np.pi * u / Ta
            sin2 = np.sin(x) ** 2
            return (0.5 * a_p * (0.5 * u * u - Ta * Ta / (2.0 * np.pi ** 2) * sin2),
                    0.5 * a_p * (u - Ta / (2.0 * np.pi) * np.sin(2.0 * x)),
                    a_p * sin2)

        acc = tau < Ta
        dec = tau > T - Ta
        sm = 0.5 * vc * Ta + vc * (tau - Ta)
        vm = vc.copy()
        am = np.zeros(tau.shape)
        ra = ramp(np.where(acc, tau, 0.0))
        rd = ramp(np.where(dec, T - tau, 0.0))
        sm = np.where(acc, ra[0], np.where(dec, dist - rd[0], sm))
        vm = np.where(acc, ra[1], np.where(dec, rd[1], vm))
        am = np.where(acc, ra[2], np.where(dec, -rd[2], am))
        s[moving] = s_from + sm
        v[moving] = vm
        a[moving] = am
        return self._placement(t, s, v, a)


def motion_profile(start_chainage_m: float, length_m: float, fix_spacing_m: float,
                   static_s: float, stop_s: float, speed_m_s: float,
                   accel_time_s: float, turn_at_stops=(), turn_s: float = 10.0, lift_at_stops=(),
                   lift_tilt_rad: float = 0.15, placement_offset_m: float = 0.0) -> MotionProfile:
    """Stops every ``fix_spacing_m`` (and at the end), raised-cosine legs between them; the
    trolley is turned around at the middle of the stops ``turn_at_stops``.

    Returns
    -------
    MotionProfile
    """
    if not (length_m > 0 and fix_spacing_m > 0 and speed_m_s > 0 and accel_time_s > 0):
        raise ValueError("length, fix spacing, speed and acceleration time must be positive")
    if static_s < 0 or stop_s < 0:
        raise ValueError("static_s and stop_s must not be negative")
    n_full = int(np.floor(length_m / fix_spacing_m + 1e-9))
    offsets = fix_spacing_m * np.arange(n_full + 1)
    if length_m - offsets[-1] > 1e-6:
        offsets = np.append(offsets, length_m)
    stops = start_chainage_m + offsets
    dist = np.diff(stops)
    speed = np.minimum(speed_m_s, dist / accel_time_s)
    duration = dist / speed + accel_time_s
    m = stops.size
    stop_start = np.empty(m)
    stop_end = np.empty(m)
    leg_start = np.empty(m - 1)
    t = 0.0
    stop_start[0], stop_end[0] = 0.0, static_s
    t = static_s
    for i in range(m - 1):  # one iteration per stop, not per sample
        leg_start[i] = t
        t += duration[i]
        stop_start[i + 1] = t
        t += stop_s
        stop_end[i + 1] = t
    turns = np.unique(np.asarray(turn_at_stops, dtype=int))
    lifts = np.unique(np.asarray(lift_at_stops, dtype=int))
    for name, ks in (("turn_at_stops", turns), ("lift_at_stops", lifts)):
        if ks.size and (ks[0] < 1 or ks[-1] > m - 1):
            raise ValueError(f"{name} must name stops 1..{m - 1} (stop 0 is the static alignment)")
    if np.intersect1d(turns, lifts).size:
        raise ValueError("a stop cannot have both a turn and a lift")
    if (turns.size or lifts.size) and (not turn_s > 0 or stop_s < turn_s + 4.0):
        raise ValueError(f"a turn of {turn_s:g} s needs stops of at least {turn_s + 4.0:g} s (stop_s = {stop_s:g})")
    k = np.concatenate([turns, lifts]).astype(int)
    order = np.argsort(k)
    k = k[order]
    angle = np.concatenate([np.full(turns.size, np.pi), np.zeros(lifts.size)])[order]
    tilt = np.concatenate([np.zeros(turns.size), np.full(lifts.size, float(lift_tilt_rad))])[order]
    middle = 0.5 * (stop_start[k] + stop_end[k])
    return MotionProfile(stop_chainage_m=stops, stop_start_s=stop_start, stop_end_s=stop_end,
                         leg_start_s=leg_start, leg_duration_s=duration, leg_speed_m_s=speed,
                         accel_time_s=float(accel_time_s), duration_s=float(t),
                         handling_start_s=middle - 0.5 * turn_s, handling_angle_rad=angle,
                         handling_tilt_rad=tilt, handling_offset_m=np.full(k.size, float(placement_offset_m)),
                         handling_stop=k, turn_s=float(turn_s))


# ------------------------------------------------------------------------------------------
# results
# ------------------------------------------------------------------------------------------
@dataclass
class TruthProfile:
    """The truth on a chainage grid (the rows of ``truth.csv``), SI units.

    Attributes
    ----------
    chainage_m, E_m, N_m, H_m : track reference point.
    roll_rad, pitch_rad, yaw_rad : trolley attitude (ZYX, NED).
    gauge_m : true gauge. cant_m : rail_spacing * sin(roll).
    lateral_m, vertical_m : true offset from the design (+ right, + up).
    """

    chainage_m: np.ndarray
    E_m: np.ndarray
    N_m: np.ndarray
    H_m: np.ndarray
    roll_rad: np.ndarray
    pitch_rad: np.ndarray
    yaw_rad: np.ndarray
    gauge_m: np.ndarray
    cant_m: np.ndarray
    lateral_m: np.ndarray
    vertical_m: np.ndarray


@dataclass
class TruthTrack:
    """The truth at the IMU sample times (arrays of shape (N,)).

    Attributes
    ----------
    t_s, chainage_m, E_m, N_m, H_m, roll_rad, pitch_rad, yaw_rad, gauge_m : reference point
        and trolley attitude at each IMU time.
    geometry : the chainage-domain truth (for :meth:`resampled`, :meth:`at_chainage`).
    motion : the motion profile (stop times and chainages).
    imu_mounting_rad : true IMU-to-trolley mounting angles (nominal + residual).
    """

    t_s: np.ndarray
    chainage_m: np.ndarray
    E_m: np.ndarray
    N_m: np.ndarray
    H_m: np.ndarray
    roll_rad: np.ndarray
    pitch_rad: np.ndarray
    yaw_rad: np.ndarray
    gauge_m: np.ndarray
    geometry: TruthGeometry | None = None
    motion: MotionProfile | None = None
    imu_mounting_rad: np.ndarray | None = None

    def at_chainage(self, chainage_m) -> TruthProfile:
        """The truth at arbitrary chainages."""
        g = self.geometry
        s = np.asarray(chainage_m, dtype=float)
        p = g.position(s)
        dp = g.position(s, 1)
        ex = g.extras(s)
        roll, pitch, yaw = g.attitude(s, dp)
        enh = g.grid_enh(p)
        return TruthProfile(chainage_m=s, E_m=enh[..., 0],
                            N_m=enh[..., 1], H_m=enh[..., 2], roll_rad=roll,
                            pitch_rad=pitch, yaw_rad=yaw, gauge_m=ex[..., 1],
                            cant_m=g.rail_spacing_m * np.sin(roll), lateral_m=ex[..., 2],
                            vertical_m=ex[..., 3])

    def resampled(self, step_m: float = 0.1) -> TruthProfile:
        """The truth every ``step_m`` of chainage over the surveyed stretch (truth.csv rows)."""
        g = self.geometry
        n = int(np.floor((g.end_chainage_m - g.start_chainage_m) / step_m + 1e-9))
        inv = 1.0 / step_m
        if abs(inv - round(inv)) < 1e-9 and float(g.start_chainage_m).is_integer():
            # k / 10 is the double nearest the decimal k * 0.1: the CSV stays short and exact
            s = g.start_chainage_m + np.arange(n + 1) / round(inv)
        else:
            s = g.start_chainage_m + step_m * np.arange(n + 1)
        return self.at_chainage(s)


@dataclass
class SimulatedSurvey:
    """A simulated survey: the raw session as the devices would record it, and the truth."""

    session: RawSession
    truth: TruthTrack
    config: SimulationConfig


# ------------------------------------------------------------------------------------------
# the simulation
# ------------------------------------------------------------------------------------------
def _gauss_markov(rng: np.random.Generator, n: int, sigma: np.ndarray, tau_s: float,
                  dt: float) -> np.ndarray:
    """First-order Gauss-Markov sequences (n, k), stationary sigma, started stationary."""
    from scipy.signal import lfilter

    phi = np.exp(-dt / tau_s)
    x0 = rng.standard_normal(sigma.size) * sigma
    w = rng.standard_normal((sigma.size, n)) * (sigma * np.sqrt(1.0 - phi * phi))[:, None]
    y, _ = lfilter([1.0], [1.0, -phi], w, axis=-1, zi=(phi * x0)[:, None])
    return y.T


def _kinematics(geo: TruthGeometry, motion: MotionProfile, t: np.ndarray, latitude0: float):
    """Reference point kinematics at times t: everything the strapdown synthesis needs."""
    s, sd, sdd = motion.evaluate(t)
    p = geo.position(s)
    dp = geo.position(s, 1)
    ddp = geo.position(s, 2)
    roll, pitch, yaw = geo.attitude(s, dp)
    # grid ENH -> NED
    t_n = np.column_stack([dp[:, 1], dp[:, 0], -dp[:, 2]])
    tt_n = np.column_stack([ddp[:, 1], ddp[:, 0], -ddp[:, 2]])
    v_n = t_n * sd[:, None]
    a_n = tt_n * (sd * sd)[:, None] + t_n * sdd[:, None]
    h = p[:, 2]
    lat = latitude0 + p[:, 1] / (EARTH_RADIUS_M + h)
    q = quat_from_euler(roll, pitch, yaw)
    if motion.handling_start_s.size:
        q = _quat_mul(q, handling_quat(motion, t))
        roll, pitch, yaw = euler_from_quat(q)
    return dict(s=s, p=p, q=q, roll=roll, pitch=pitch, yaw=yaw, v_n=v_n, a_n=a_n, lat=lat, h=h)


def simulate_survey(alignment, config: SimulationConfig = SimulationConfig(),
                    progress: Callable[[str, float], None] | None = None) -> SimulatedSurvey:
    """Simulate a stop-and-go trolley survey along a design alignment.

    Parameters
    ----------
    alignment : trolley.alignment.Alignment
        Design geometry (``evaluate``, ``start_chainage_m``, ``end_chainage_m``).
    config : SimulationConfig
    progress : optional callable ``progress(step, fraction)`` (the convention of
        :func:`trolley.engine.process_session`), called once per chunk of IMU samples; it does
        not change the random draws.

    Returns
    -------
    SimulatedSurvey
        ``session``: the raw session (SessionMeta with ``design_alignment=None``; the caller
        names the design file); ``truth``: the truth at the IMU times and as splines.

    References
    ----------
    Jiang 2017 Sec. 2-3 (sensor set, error models Eq. 1, 7, 10, 11); module docstring for the
    truth model.
    """
    cfg = config
    rng = np.random.default_rng(cfg.seed)
    s0 = float(alignment.start_chainage_m if cfg.start_chainage_m is None
               else cfg.start_chainage_m)
    a_start, a_end = float(alignment.start_chainage_m), float(alignment.end_chainage_m)
    if s0 < a_start - 1e-9 or s0 + cfg.length_m > a_end + 1e-9:
        raise ValueError(f"survey {s0:.3f}..{s0 + cfg.length_m:.3f} m leaves the alignment "
                         f"({a_start:.3f}..{a_end:.3f} m)")
    grid = None
    if cfg.crs:
        # the site where the engine takes it: the centroid of the stops (of the fixes)
        stops = alignment.evaluate(np.arange(s0, s0 + cfg.length_m + 1e-9, cfg.fix_spacing_m))
        grid = site_factors(cfg.crs, np.column_stack([stops.E_m, stops.N_m, stops.H_m]))
        cfg = replace(cfg, latitude_rad=grid.latitude_rad)
    track_rng = rng if cfg.track_seed is None else np.random.default_rng(cfg.track_seed)
    geo = truth_geometry(alignment, s0, cfg.length_m, cfg.irregularity_rms_m,
                         cfg.trolley.rail_spacing_m, cfg.trolley.nominal_gauge_m, track_rng, grid=grid)
    motion = motion_profile(s0, cfg.length_m, cfg.fix_spacing_m, cfg.static_s, cfg.stop_s,
                            cfg.speed_m_s, cfg.accel_time_s, cfg.turn_at_stops, cfg.turn_s,
                            cfg.lift_at_stops, cfg.lift_tilt_rad, cfg.placement_offset_m)

    # --- IMU mounting: nominal (written to session.toml) + unknown residual
    nominal = np.asarray(cfg.trolley.imu_misalignment_rad, dtype=float)
    residual = rng.standard_normal(3) * cfg.imu_residual_misalignment_rad
    mounting = nominal + (residual if cfg.errors else 0.0)
    c_b_bt = _dcm_from_euler(*mounting)  # IMU -> trolley

    # --- truth kinematics and error-free IMU, chunk by chunk
    rate = float(cfg.imu_rate_hz)
    dt = 1.0 / rate
    n_imu = int(np.ceil(motion.duration_s * rate - 1e-9))
    t_imu = np.arange(1, n_imu + 1) / rate
    w_b = np.empty((n_imu, 3))
    f_b = np.empty((n_imu, 3))
    tr = {k: np.empty(n_imu) for k in ("s", "E", "N", "H", "roll", "pitch", "yaw")}
    for i0 in range(0, n_imu, _CHUNK):
        i1 = min(i0 + _CHUNK, n_imu)
        if progress is not None:
            progress("simulating the truth and the IMU", i0 / n_imu)
        k = np.arange(i0, i1 + 1)
        t_half = np.empty(2 * (i1 - i0) + 1)
        t_half[0::2] = k / rate                       # interval ends t_{k-1}, t_k
        t_half[1::2] = (k[:-1] + 0.5) / rate          # interval midpoints
        kin = _kinematics(geo, motion, t_half, cfg.latitude_rad)
        q_end = kin["q"][0::2]
        dq = _quat_mul(_quat_conj(q_end[:-1]), q_end[1:])
        w_nb = _rotvec_from_quat(dq) * rate
        mid = slice(1, None, 2)
        q_mid = kin["q"][mid]
        lat, h, v_n = kin["lat"][mid], kin["h"][mid], kin["v_n"][mid]
        w_ie = earth_rate_n(lat)
        w_en = transport_rate_n(v_n, lat, h)
        g_n = np.zeros_like(v_n)
        g_n[:, 2] = normal_gravity_m_s2(lat, h)
        f_n = kin["a_n"][mid] + np.cross(2.0 * w_ie + w_en, v_n) - g_n
        q_inv = _quat_conj(q_mid)
        w_bt = w_nb + _quat_rotate(q_inv, w_ie + w_en)
        f_bt = _quat_rotate(q_inv, f_n)
        # row-vector form of C_bt^b x = (C_b^bt)^T x
        w_b[i0:i1] = w_bt @ c_b_bt
        f_b[i0:i1] = f_bt @ c_b_bt
        end = slice(2, None, 2)
        tr["s"][i0:i1] = kin["s"][end]
        enh_end = geo.grid_enh(kin["p"][end])
        tr["E"][i0:i1] = enh_end[:, 0]
        tr["N"][i0:i1] = enh_end[:, 1]
        tr["H"][i0:i1] = kin["p"][end, 2]
        tr["roll"][i0:i1] = kin["roll"][end]
        tr["pitch"][i0:i1] = kin["pitch"][end]
        tr["yaw"][i0:i1] = kin["yaw"][end]
    gauge_truth = geo.extras(tr["s"])[:, 1]

    # --- IMU errors
    imu = cfg.imu
    if cfg.errors:
        bi = np.full(3, imu.gyro_bias_instability_rad_s)
        gyro_bias = rng.standard_normal(3) * imu.gyro_turn_on_bias_rad_s + _gauss_markov(
            rng, n_imu, bi, cfg.gyro_correlation_time_s, dt)
        gyro_sf = rng.standard_normal(3) * imu.gyro_scale_factor
        w_meas = w_b * (1.0 + gyro_sf) + gyro_bias \
            + rng.standard_normal((n_imu, 3)) * (imu.gyro_arw_rad_sqrt_s * np.sqrt(rate))
        accel_bias = rng.standard_normal(3) * imu.accel_bias_m_s2
        f_meas = f_b + accel_bias \
            + rng.standard_normal((n_imu, 3)) * (imu.accel_vrw_m_s_sqrt_s * np.sqrt(rate))
    else:
        w_meas, f_meas = w_b, f_b

    # --- odometer: 3-D path length of the reference point, scale error, quantisation
    odo = cfg.odometer
    n_odo = int(np.floor(motion.duration_s * cfg.odometer_rate_hz + 1e-9))
    t_odo = np.arange(0, n_odo + 1) / cfg.odometer_rate_hz
    path = geo.arclength(motion.evaluate(t_odo)[0])
    # a turned trolley rolls backwards in its own frame: the wheel counts down; a trolley the crew
    # holds off the track does not turn its wheel
    mid_odo = 0.5 * (t_odo[1:] + t_odo[:-1])
    dpath = np.diff(path) * motion.facing(mid_odo) * ~motion.handled(mid_odo)
    if cfg.errors:
        dk = odo.scale_error * rng.standard_normal() + np.cumsum(
            rng.standard_normal(n_odo) * (odo.scale_noise_per_sqrt_s
                                          * np.sqrt(1.0 / cfg.odometer_rate_hz)))
        dpath = dpath * (1.0 + dk)
    dist = np.concatenate([[0.0], np.cumsum(dpath)])
    if odo.resolution_m > 0:
        counts = np.floor(dist / odo.resolution_m + 1e-9)
        inv = 1.0 / odo.resolution_m
        dist = counts / round(inv) if abs(inv - round(inv)) < 1e-6 else counts * odo.resolution_m

    # --- total-station fixes of the prism at the middle of each stop
    m = max(int(cfg.fixes_per_stop), 1)
    frac = (np.arange(m) + 1.0) / (m + 1.0)
    # a stop with a turn is two standstills, before and after it, with m fixes each
    n_stop = motion.stop_chainage_m.size
    turn_stop = motion.handling_stop
    win_start = np.concatenate([motion.stop_start_s, motion.handling_start_s + motion.turn_s])
    win_end = np.concatenate([motion.stop_end_s, motion.stop_end_s[turn_stop]])
    win_end[turn_stop] = motion.handling_start_s
    win_stop = np.concatenate([np.arange(n_stop), turn_stop])
    order = np.argsort(win_start, kind="stable")
    t_fix = (win_start[order][:, None]
             + frac[None, :] * (win_end - win_start)[order][:, None]).ravel()
    stop_idx = np.repeat(win_stop[order], m)
    s_fix = motion.evaluate(t_fix)[0]
    p_fix = geo.position(s_fix)
    r, pch, y = geo.attitude(s_fix)
    q_fix = _quat_mul(quat_from_euler(r, pch, y), handling_quat(motion, t_fix))
    lever_n = _quat_rotate(q_fix,
                           np.broadcast_to(np.asarray(cfg.trolley.prism_lever_arm_m, float),
                                           (s_fix.size, 3)))
    enh = geo.grid_enh(np.column_stack([p_fix[:, 0] + lever_n[:, 1], p_fix[:, 1] + lever_n[:, 0],
                                        p_fix[:, 2] - lever_n[:, 2]]))
    if cfg.errors:
        enh = enh + rng.standard_normal(enh.shape) * cfg.fix_sigma_m
    # a stop is labelled by the CPIII pair it stands beside (pairs every fix_spacing_m from
    # the alignment start); a final stop between pairs gets ST<stop index>
    pos = (motion.stop_chainage_m - a_start) / cfg.fix_spacing_m
    pair = np.rint(pos).astype(int)
    stop_label = [f"CP{pair[i]:04d}" if abs(pos[i] - pair[i]) < 1e-6 else f"ST{i:04d}"
                  for i in range(pos.size)]
    labels = np.array([stop_label[i] for i in stop_idx], dtype=object)
    fixes = Fixes(t_s=t_fix, point=labels, enh_m=enh,
                  sigma_m=np.full(enh.shape, float(cfg.fix_sigma_m)))

    # --- gauge sensor
    n_g = int(np.floor(motion.duration_s * cfg.gauge_rate_hz + 1e-9))
    t_g = np.arange(1, n_g + 1) / cfg.gauge_rate_hz
    gauge = geo.extras(motion.evaluate(t_g)[0])[:, 1]
    if cfg.errors:
        gauge = gauge + rng.standard_normal(n_g) * cfg.gauge_sigma_m

    heading_known = (not imu.gyrocompassing) if cfg.initial_heading is None \
        else bool(cfg.initial_heading)
    initial_heading = float(geo.attitude(np.array([s0]))[2][0]) if heading_known else float("nan")
    meta = SessionMeta(latitude_rad=float(cfg.latitude_rad), height_m=float(cfg.height_m),
                       trolley=cfg.trolley, imu=imu, odometer=odo,
                       fix_sigma_m=float(cfg.fix_sigma_m), static_s=float(cfg.static_s),
                       initial_heading_rad=initial_heading, design_alignment=None,
                       crs=cfg.crs if cfg.crs_in_session else None)
    session = RawSession(meta=meta, imu_t_s=t_imu, imu_w_rad_s=w_meas, imu_f_m_s2=f_meas,
                         odo_t_s=t_odo, odo_distance_m=dist, fixes=fixes,
                         gauge_t_s=t_g, gauge_m=gauge)
    truth = TruthTrack(t_s=t_imu, chainage_m=tr["s"], E_m=tr["E"], N_m=tr["N"], H_m=tr["H"],
                       roll_rad=tr["roll"], pitch_rad=tr["pitch"], yaw_rad=tr["yaw"],
                       gauge_m=gauge_truth, geometry=geo, motion=motion,
                       imu_mounting_rad=mounting)
    return SimulatedSurvey(session=session, truth=truth, config=cfg)


def with_errors_off(config: SimulationConfig) -> SimulationConfig:
    """The same configuration with every sensor error switched off (tests, checks)."""
    return replace(config, errors=False)
