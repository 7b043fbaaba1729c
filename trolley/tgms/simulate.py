"""Synthetic TGMS recordings with known truth.

What is simulated (all in SI, TGMS frame FRD with the IMU at its origin):

* **Design track**: straights, clothoid transitions and arcs (R 500 m right, R 400 m left)
  alternating, cant ramps on the transitions (0.06 rad ~ 90 mm on the arcs), grades of +-0.8 % joined by
  parabolic vertical curves (:func:`design_alignment`).
* **Irregularities** of the two rails from the German track spectra for *low* disturbance
  (Claus & Schiehlen's fit used in vehicle dynamics), one-sided in the spatial angular frequency
  Omega (rad/m), variance = integral over (0, inf) of S dOmega::

      S_al(O) = A_a Oc^2 / ((O^2 + Or^2)(O^2 + Oc^2))             alignment,       m^2/(rad/m)
      S_vp(O) = A_v Oc^2 / ((O^2 + Or^2)(O^2 + Oc^2))             vertical profile
      S_cl(O) = A_v b^-2 Oc^2 O^2 / ((O^2+Or^2)(O^2+Oc^2)(O^2+Os^2))  cross-level angle, rad^2/(rad/m)
      S_gv(O) = A_g Oc^2 O^2 / ((O^2+Or^2)(O^2+Oc^2)(O^2+Os^2))     gauge variation

  with Oc = 0.8246, Or = 0.0206, Os = 0.4380 rad/m, A_a = 2.119e-7, A_v = 4.032e-7,
  A_g = 0.532e-7 m rad, b = 0.75 m; wavelengths 1-300 m, plus four isolated defects (a 3 mm
  lateral kink, a 4 mm dip, a 3 mm gauge widening and a 3 mm cross-level fault).
* **Vehicle body** carrying the TGMS (think bogie frame): it follows the rails plus band-limited
  sway (2 mm rms, 0.5-3 Hz), bounce (1.5 mm rms, 1-4 Hz), roll (1 mrad rms, 0.5-2.5 Hz), pitch and
  yaw (0.5 mrad rms), and a quasi-static offset and roll proportional to the cant deficiency.
  The speed varies by about +-10 % around the nominal value after a start from rest.
* **IMU** from the full 3-D kinematics: attitude and position of the TGMS in NED from the exact
  design pose, irregularities and body motion, differentiated numerically on a 4x oversampled
  grid; Earth rate and Coriolis included; errors from ``trolley.sensors`` (MEMS preset: constant
  biases, white noise).
* **Encoder**: wheel diameter 0.1 % off its nominal value, quantised counts, and (by default;
  ``CONSTANT_ENCODER`` switches them off) two errors the odometry's single-scale model does not
  have, so that its validation is not self-referential:

  - *creep* proportional to the longitudinal acceleration, xi = c a (``encoder_creep_s2_m``,
    c = 1e-4 s^2/m when on): the wheel turns by (1 - xi) ds. A traction or braking force F_x at
    the contact needs a creepage F_x / f11 (Kalker's linear theory; f11 = G a b c11 ~ 1e7 N for
    a 0.84 m wheel on 60E1 under 60 kN). An unpowered axle only has to spin up its own inertia,
    F_x ~ (I / r^2) a ~ 340 N per wheel at 1 m/s^2 (I ~ 120 kg m^2 per wheelset), xi ~ 3e-5 a;
    a braked or driven axle carries ~5 t of vehicle per wheel, F_x ~ 5 kN, xi ~ 5e-4 a. 1e-4 is
    in between. The station error it leaves is c (v^2 - v_0^2) / 2: ~1 cm after the start to
    15 m/s, a nearly constant offset the scale model (zero at s0) cannot follow.
  - a slow random variation of the rolling radius along s, r = r_0 (1 + eps(s))
    (``rolling_radius_rms``, 1e-4 when on; ``rolling_radius_corr_m``, 100 m): a first-order
    Gauss-Markov process in s (exponential autocorrelation exp(-|ds| / L), the usual model of a
    slowly wandering scale factor). Sources: the dynamic wheel load (the Hertzian approach,
    ~0.1 mm under 60 kN, is 2.4e-4 of r = 0.42 m and the load varies by 20-40 %), the wheelset's
    lateral position on the conical tread (equivalent conicity 0.1 times 1 mm is 2.4e-4 of r),
    contamination films and temperature (steel 1.2e-5 /K). Over a ride of length S it adds a
    random-walk-like station error of about eps_rms sqrt(2 L S) (2.4 cm for 300 m), of which the
    single scale fits the mean.

  The wheel's distance is int (1 - c a) / (1 + eps(s)) ds (clipped at 0, so the counts stay
  monotone); eps is drawn from the recording's rng after every other draw, so switching the
  drift on changes the encoder counts only.
* **Cameras**: each images the real rail head (60E1/54E1 outline tilted 1:40) cut by its laser
  plane, only the part facing the camera, with Brown-Conrady distortion, 0.2 px noise,
  2 % outlier points (reflections), 1 % dropped frames and 1 % frames without the gauge face.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from trolley import sensors, units
from trolley.alignment import Alignment, Arc, CantProfile, Clothoid, HorizontalAlignment, Line, VerticalProfile
from trolley.tgms.camera import Camera, look_at, project
from trolley.tgms.config import EncoderSettings, TgmsConfig, TrackSettings
from trolley.tgms.profiles import outline_normals, rail_profile
from trolley.tgms.recording import LaserPoints, Recording
from trolley.tgms.track import GRAVITY_M_S2, angular_velocity_body, ned_position, track_rotation

# German track spectra, low disturbance
_OC, _OR, _OS = 0.8246, 0.0206, 0.4380
_AA, _AV, _AG, _B = 2.119e-7, 4.032e-7, 0.532e-7, 0.75


def irregularity_psd(kind: str, omega_rad_m: np.ndarray) -> np.ndarray:
    """One-sided PSD of the simulated irregularities (see module docstring), SI units.

    ``kind``: "alignment", "vertical" (m^2/(rad/m)), "cross_level_angle" (rad^2/(rad/m)), "gauge".
    """
    o2 = np.asarray(omega_rad_m, float) ** 2
    base = _OC ** 2 / ((o2 + _OR ** 2) * (o2 + _OC ** 2))
    if kind == "alignment":
        return _AA * base
    if kind == "vertical":
        return _AV * base
    if kind == "cross_level_angle":
        return _AV / _B ** 2 * base * o2 / (o2 + _OS ** 2)
    if kind == "gauge":
        return _AG * base * o2 / (o2 + _OS ** 2)
    raise ValueError(kind)


@dataclass(frozen=True)
class SimulationSettings:
    """Settings of a synthetic recording (SI).

    Attributes
    ----------
    length_m : length of track ridden.
    speed_m_s : nominal forward speed.
    seed : random seed.
    imu : name of the IMU preset in ``trolley.sensors.IMU_PRESETS``.
    imu_rate_hz, camera_rate_hz : sampling rates.
    rail_profile, rail_inclination, half_rail_spacing_m : track settings.
    tgms_height_m : height of the IMU above the rail tops.
    pixel_noise_px, outlier_fraction, dropout_fraction, no_gauge_face_fraction : camera errors.
    point_spacing_m : spacing of the laser points along the head outline.
    laser_plane_x_m : the laser planes are x = laser_plane_x_m in the TGMS frame (ahead of the IMU).
    wheel_scale_error : relative error of the nominal wheel diameter.
    encoder_creep_s2_m : encoder-wheel creepage per unit longitudinal acceleration, s^2/m
        (default 1e-4, see the module docstring; 0 = off).
    rolling_radius_rms : rms of the relative rolling-radius variation along s (default 1e-4;
        0 = off).
    rolling_radius_corr_m : its correlation length (exponential autocorrelation), m.
    latitude_deg : for the Earth rate.
    body_scale : multiplies all body-motion amplitudes (0 = TGMS rigid on the rails).
    irregularity_scale : multiplies the random irregularities.
    """

    length_m: float = 200.0
    speed_m_s: float = 10.0
    seed: int = 0
    imu: str = "mems"
    imu_rate_hz: float = 500.0
    camera_rate_hz: float = 100.0
    rail_profile: str = "60E1"
    rail_inclination: float = 40.0
    half_rail_spacing_m: float = 0.7175
    tgms_height_m: float = 0.45
    pixel_noise_px: float = 0.2
    outlier_fraction: float = 0.02
    dropout_fraction: float = 0.01
    no_gauge_face_fraction: float = 0.01
    point_spacing_m: float = 1.0e-3
    laser_plane_x_m: float = 0.0
    wheel_scale_error: float = 1e-3
    encoder_creep_s2_m: float = 1e-4
    rolling_radius_rms: float = 1e-4
    rolling_radius_corr_m: float = 100.0
    latitude_deg: float = 40.0
    body_scale: float = 1.0
    irregularity_scale: float = 1.0


# the encoder errors beyond the constant diameter error (the defaults; figures justified in the
# module docstring), and the settings that switch them off: ``dataclasses.replace(settings,
# **CONSTANT_ENCODER)`` gives the encoder the single-scale model of the odometry exactly
ENCODER_DRIFT = {"encoder_creep_s2_m": 1e-4, "rolling_radius_rms": 1e-4, "rolling_radius_corr_m": 100.0}
CONSTANT_ENCODER = {"encoder_creep_s2_m": 0.0, "rolling_radius_rms": 0.0}


@dataclass
class Truth:
    """True values on a uniform station grid (``truth.csv``).

    Attributes
    ----------
    s_m : station.
    gauge_variation_mm, cross_level_mm, alignment_mm, vertical_profile_mm : published signs.
    t_s : time at which the IMU passed s.
    r_y_m, r_z_m : TGMS origin relative to the design TF, TF axes FRD.
    roll_rad, pitch_rad, yaw_rad : TGMS attitude relative to the TF (FRD Euler ZYX).
    """

    s_m: np.ndarray
    gauge_variation_mm: np.ndarray
    cross_level_mm: np.ndarray
    alignment_mm: np.ndarray
    vertical_profile_mm: np.ndarray
    t_s: np.ndarray
    r_y_m: np.ndarray
    r_z_m: np.ndarray
    roll_rad: np.ndarray
    pitch_rad: np.ndarray
    yaw_rad: np.ndarray


def design_alignment(length_m: float) -> Alignment:
    """A design track of at least ``length_m`` + 40 m: blocks of 200 m (straight 30, clothoid 40,
    arc 60, clothoid 40, straight 30) with curves alternately right (R 500) and left (R 400),
    cant 0.06 rad ramped on the clothoids, grades +0.8/-0.5 % with 80 m vertical curves."""
    n_blocks = int(np.ceil((length_m + 40.0) / 200.0))
    elements, cant_s, cant_v = [], [0.0], [0.0]
    s = 0.0
    for i in range(n_blocks):
        k = 1 / 500.0 if i % 2 == 0 else -1 / 400.0
        c = 0.06 * np.sign(k)
        elements += [Line(30.0), Clothoid(40.0, 0.0, k), Arc(60.0, k), Clothoid(40.0, k, 0.0), Line(30.0)]
        cant_s += [s + 30.0, s + 70.0, s + 130.0, s + 170.0]
        cant_v += [0.0, c, c, 0.0]
        s += 200.0
    hz = HorizontalAlignment.from_elements(0.0, 0.0, 0.3, elements)
    n_pvi = int(np.ceil(s / 300.0)) + 1
    pvi_s = np.linspace(0.0, s, n_pvi)
    grades = np.where(np.arange(n_pvi - 1) % 2 == 0, 0.008, -0.005)
    pvi_h = 100.0 + np.concatenate([[0.0], np.cumsum(grades * np.diff(pvi_s))])
    L = np.full(n_pvi, 80.0)
    L[0] = L[-1] = 0.0
    vp = VerticalProfile.from_pvis(pvi_s, pvi_h, L)
    cp = CantProfile.from_stations(np.array(cant_s[1:]), np.array(cant_v[1:]))
    return Alignment(hz, vp, cp, name="tgms-sim")


def default_cameras(half_rail_spacing_m: float = 0.7175, tgms_height_m: float = 0.45,
                    laser_plane_x_m: float = 0.0) -> dict[str, Camera]:
    """Two cameras 0.30 m behind the laser plane x = laser_plane_x_m, 0.40 m above the rail tops
    and 0.17 m inboard of the gauge points, looking at the gauge corners; 648x488 px, f = 1400 px,
    mild distortion."""
    K = np.array([[1400.0, 0.0, 324.0], [0.0, 1400.0, 244.0], [0.0, 0.0, 1.0]])
    cams = {}
    for side, sgn in (("left", -1.0), ("right", 1.0)):
        c = np.array([laser_plane_x_m - 0.30, sgn * (half_rail_spacing_m - 0.17), tgms_height_m - 0.40])
        target = np.array([laser_plane_x_m, sgn * (half_rail_spacing_m + 0.012), tgms_height_m + 0.006])
        dist = np.array([-0.08, 0.02, 1e-4, -1e-4]) * (1 if side == "left" else 1.1)
        cams[side] = Camera(K=K, R_tgms_cam=look_at(c, target), t_tgms_cam_m=c, distortion=dist,
                            laser_plane=np.array([1.0, 0.0, 0.0, -laser_plane_x_m]), name=side)
    return cams


def _spectral_profile(rng, kind: str, s_grid: np.ndarray, scale: float) -> np.ndarray:
    n = len(s_grid)
    ds = s_grid[1] - s_grid[0]
    omega = 2 * np.pi * np.fft.rfftfreq(n, ds)
    d_omega = omega[1] - omega[0]
    band = (omega >= 2 * np.pi / 300.0) & (omega <= 2 * np.pi / 1.0)
    amp = np.sqrt(2 * irregularity_psd(kind, np.maximum(omega, 1e-9)) * d_omega) * band
    spec = amp * np.exp(1j * rng.uniform(0, 2 * np.pi, len(omega)))
    # sum of cosines a_k cos(omega_k s + phi_k) via the inverse real FFT
    return scale * np.fft.irfft(spec, n) * n / 2.0


def _band_noise(rng, t: np.ndarray, rms: float, f_lo: float, f_hi: float, n: int = 30) -> np.ndarray:
    f = rng.uniform(f_lo, f_hi, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    return rms * np.sqrt(2.0 / n) * np.cos(2 * np.pi * np.outer(t, f) + ph).sum(axis=1)


def rolling_radius_variation(rng, s_m: np.ndarray, rms: float, corr_m: float, ds_m: float = 0.5) -> np.ndarray:
    """Relative rolling-radius variation eps(s): a stationary first-order Gauss-Markov process in s.

    Parameters
    ----------
    rng : numpy Generator (the recording's).
    s_m : stations at which eps is wanted (any order).
    rms : its standard deviation.
    corr_m : correlation length L (autocorrelation exp(-|ds| / L)).
    ds_m : step of the grid the process is generated on (then interpolated linearly).

    Returns
    -------
    eps on ``s_m`` (zeros, without drawing, when ``rms`` is 0).

    References
    ----------
    Exact discretisation of the Ornstein-Uhlenbeck process: x_n = phi x_(n-1) + rms sqrt(1 - phi^2) w_n,
    phi = exp(-ds / L), started from its stationary distribution (e.g. Gelb, Applied Optimal
    Estimation, 1974, Sec. 3.8, for the first-order Markov model of slowly varying sensor errors).
    """
    s_m = np.asarray(s_m, float)
    if rms == 0.0:
        return np.zeros_like(s_m)
    from scipy.signal import lfilter
    grid = np.arange(s_m.min(), s_m.max() + 2 * ds_m, ds_m)
    phi = np.exp(-ds_m / corr_m)
    w = rng.normal(0.0, 1.0, len(grid))
    x0 = rng.normal(0.0, rms)
    # the AR(1) recursion as a linear filter (vectorised); zi = phi x0 starts it stationary
    x, _ = lfilter([rms * np.sqrt(1.0 - phi * phi)], [1.0, -phi], w, zi=[phi * x0])
    return np.interp(s_m, grid, x)


def encoder_distance(s_m: np.ndarray, a_m_s2: np.ndarray, eps: np.ndarray, creep_s2_m: float) -> np.ndarray:
    """Distance rolled by the encoder wheel's circumference (at its nominal radius) from s_m[0].

    Parameters
    ----------
    s_m : true stations of the samples (non-decreasing).
    a_m_s2 : longitudinal acceleration at the samples.
    eps : relative rolling-radius variation at the samples.
    creep_s2_m : creepage per unit acceleration c (xi = c a).

    Returns
    -------
    int_(s_m[0])^s (1 - c a) / (1 + eps) ds, non-decreasing (the integrand is clipped at 0: the wheel
    does not turn backwards while the vehicle moves forwards).

    References
    ----------
    Creepage xi = (v - omega r) / v = F_x / f11: Kalker, Three-dimensional elastic bodies in rolling
    contact, 1990 (linear theory); figures in the module docstring.
    """
    from scipy.integrate import cumulative_trapezoid
    h = np.maximum((1.0 - creep_s2_m * np.asarray(a_m_s2)) / (1.0 + np.asarray(eps)), 0.0)
    return cumulative_trapezoid(h, s_m, initial=0.0)


def _bump(s, s0, amp, width):
    return amp * np.exp(-0.5 * ((s - s0) / width) ** 2)


class _Scenario:
    """The true world of one simulation: functions of s and t."""

    def __init__(self, st: SimulationSettings, alignment: Alignment, rng):
        self.st = st
        self.al = alignment
        s0 = alignment.start_chainage_m
        self.s_start = s0 + 10.0
        self.s_end = self.s_start + st.length_m
        grid = np.arange(s0 - 20.0, alignment.end_chainage_m + 20.0, 0.05)
        sc = st.irregularity_scale
        al = _spectral_profile(rng, "alignment", grid, sc)
        vp = _spectral_profile(rng, "vertical", grid, sc)
        cl = _spectral_profile(rng, "cross_level_angle", grid, sc) * 2 * _B
        gv = _spectral_profile(rng, "gauge", grid, sc)
        L = st.length_m
        a = self.s_start
        al += _bump(grid, a + 0.25 * L, 0.003, 1.5)
        vp += _bump(grid, a + 0.45 * L, -0.004, 1.0)
        gv += _bump(grid, a + 0.60 * L, 0.003, 2.0)
        cl += _bump(grid, a + 0.75 * L, 0.003, 1.5)
        self.irr = {k: CubicSpline(grid, v) for k, v in
                    (("al", al), ("vp", vp), ("cl", cl), ("gv", gv))}
        b = st.body_scale
        self.body = {
            "y": (b * 0.002, 0.5, 3.0), "z": (b * 0.0015, 1.0, 4.0),
            "roll": (b * 1e-3, 0.5, 2.5), "pitch": (b * 5e-4, 0.5, 3.0), "yaw": (b * 5e-4, 0.3, 2.0),
        }
        self.body_seed = rng.integers(1 << 31)
        self.speed_phase = rng.uniform(0, 2 * np.pi, 2)

    # -- irregularities (FRD track-frame rail displacements) --
    def rails(self, s):
        al, vp, cl, gv = (self.irr[k](s) for k in ("al", "vp", "cl", "gv"))
        return {"y_left": al - gv / 2, "y_right": al + gv / 2,
                "z_left": -vp - cl / 2, "z_right": -vp + cl / 2,
                "dy_left": self.irr["al"](s, 1) - self.irr["gv"](s, 1) / 2,
                "dy_right": self.irr["al"](s, 1) + self.irr["gv"](s, 1) / 2,
                "dz_left": -self.irr["vp"](s, 1) - self.irr["cl"](s, 1) / 2,
                "dz_right": -self.irr["vp"](s, 1) + self.irr["cl"](s, 1) / 2,
                "al": al, "vp": vp, "cl": cl, "gv": gv}

    def speed(self, t):
        V0 = self.st.speed_m_s
        t_ramp = max(3.0, V0 / 1.0)
        ramp = np.where(t < 1.0, 0.0, np.where(t < 1.0 + t_ramp,
                                                 0.5 - 0.5 * np.cos(np.pi * (t - 1.0) / t_ramp), 1.0))
        p = self.speed_phase
        return V0 * ramp * (1 + 0.07 * np.sin(2 * np.pi * t / 40.0 + p[0]) + 0.04 * np.sin(2 * np.pi * t / 13.0 + p[1]))

    def body_motion(self, t, s, v, a_lat):
        rng = np.random.default_rng(self.body_seed)
        out = {k: _band_noise(rng, t, *self.body[k]) for k in ("y", "z", "roll", "pitch", "yaw")}
        r = self.rails(s)
        b = self.st.body_scale
        # the body follows the track panel plus suspension motion and a quasi-static lean in curves
        r_y = r["al"] + out["y"] + b * 0.003 * a_lat
        r_z = -self.st.tgms_height_m - r["vp"] + out["z"]
        roll = r["cl"] / (2 * self.st.half_rail_spacing_m) + out["roll"] + b * 0.003 * a_lat
        pitch = self.irr["vp"](s, 1) + out["pitch"]
        yaw = self.irr["al"](s, 1) + out["yaw"]
        return r_y, r_z, roll, pitch, yaw


def _ride(sc: _Scenario, dt: float):
    """Time grid, station and speed of the ride from rest at s_start until s_end."""
    V0 = sc.st.speed_m_s
    T = 1.0 + max(3.0, V0 / 1.0) + 1.4 * sc.st.length_m / V0 + 5.0
    t = np.arange(0.0, T, dt)
    v = sc.speed(t)
    s = sc.s_start + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
    n = int(np.searchsorted(s, sc.s_end))
    return t[:n], s[:n], v[:n]


def _pose(sc: _Scenario, t, s, v):
    """World pose of the TGMS and the track at (t, s): track rotation, TGMS rotation, NED
    position and the relative pose."""
    g = sc.al.evaluate(s)
    Rt = track_rotation(g.heading_rad, g.slope_rad, g.cant_rad)
    a_lat = g.rho_h_1_m * v * v - GRAVITY_M_S2 * np.sin(g.cant_rad)
    r_y, r_z, roll, pitch, yaw = sc.body_motion(t, s, v, a_lat)
    Rrel = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))
    p = ned_position(g) + Rt.apply(np.column_stack([np.zeros_like(r_y), r_y, r_z]))
    return Rt, Rt * Rrel, p, (r_y, r_z, roll, pitch, yaw)


def _imu(sc: _Scenario, st: SimulationSettings, rng):
    over = 4
    dt = 1.0 / (st.imu_rate_hz * over)
    t, s, v = _ride(sc, dt)
    _, Rb, p, _ = _pose(sc, t, s, v)
    vel = np.gradient(p, dt, axis=0)
    acc = np.gradient(vel, dt, axis=0)
    lat = units.deg_to_rad(st.latitude_deg)
    w_ie = units.EARTH_RATE_RAD_S * np.array([np.cos(lat), 0.0, -np.sin(lat)])
    f_ned = acc + 2 * np.cross(w_ie, vel) - np.array([0.0, 0.0, GRAVITY_M_S2])
    w_b = angular_velocity_body(Rb, dt) + Rb.inv().apply(w_ie)
    f_b = Rb.inv().apply(f_ned)
    sl = slice(0, None, over)
    t, s, w_b, f_b = t[sl], s[sl], w_b[sl], f_b[sl]
    fig = sensors.IMU_PRESETS[st.imu]
    rate = st.imu_rate_hz
    n = len(t)
    w_meas = (w_b + rng.normal(0, fig.gyro_bias_instability_rad_s, 3)
              + rng.normal(0, fig.gyro_arw_rad_sqrt_s * np.sqrt(rate), (n, 3)))
    f_meas = (f_b + rng.normal(0, fig.accel_bias_m_s2, 3)
              + rng.normal(0, fig.accel_vrw_m_s_sqrt_s * np.sqrt(rate), (n, 3)))
    return t, s, w_meas, f_meas


def _laser_points(sc: _Scenario, st: SimulationSettings, cams: dict[str, Camera], t_f, s_f, v_f, rng):
    """Laser points of both cameras, in chunks of frames to bound the memory."""
    chunks = {"left": [], "right": []}
    n = len(t_f)
    for a in range(0, n, 2000):
        b = min(n, a + 2000)
        part = _laser_chunk(sc, st, cams, t_f[a:b], s_f[a:b], v_f[a:b], rng)
        for side in chunks:
            lp = part[side]
            chunks[side].append(LaserPoints(lp.frame + a, lp.t_s, lp.u_px, lp.v_px))
    return {side: LaserPoints(*(np.concatenate([getattr(c, k) for c in chunks[side]])
                                for k in ("frame", "t_s", "u_px", "v_px"))) for side in chunks}


def _laser_chunk(sc: _Scenario, st: SimulationSettings, cams: dict[str, Camera], t_f, s_f, v_f, rng):
    prof = rail_profile(st.rail_profile, st.rail_inclination)
    step = max(1, int(round(st.point_spacing_m / 2e-5)))
    outline = prof.outline_m[::step]
    normals = outline_normals(prof.outline_m)[::step]
    Rt, Rb, p, _ = _pose(sc, t_f, s_f, v_f)
    # the rail cross-section the laser plane cuts: at the station s + x_L, in its own track frame,
    # carried into the TGMS frame through the world (exact: design curvature, cant and slope
    # changes between the IMU's and the laser's stations included)
    s_c = s_f + st.laser_plane_x_m
    gc = sc.al.evaluate(s_c)
    Rc = track_rotation(gc.heading_rad, gc.slope_rad, gc.cant_rad)
    Oc = ned_position(gc)
    Rb_inv = Rb.inv()
    rails = sc.rails(s_c)
    delta = rails["cl"] / (2 * st.half_rail_spacing_m)
    cd, sd = np.cos(delta)[:, None], np.sin(delta)[:, None]
    nf, npnt = len(t_f), len(outline)
    rep = np.repeat(np.arange(nf), npnt)
    out = {}
    for side, sgn in (("left", -1.0), ("right", 1.0)):
        cam = cams[side]
        qy, qz = sgn * outline[:, 0][None, :], outline[:, 1][None, :]
        ny, nz = sgn * normals[:, 0][None, :], normals[:, 1][None, :]
        Py = sgn * st.half_rail_spacing_m + rails[f"y_{side}"][:, None] + cd * qy - sd * qz
        Pz = rails[f"z_{side}"][:, None] + sd * qy + cd * qz
        P = np.stack([np.zeros((nf, npnt)), Py, Pz], axis=-1).reshape(-1, 3)
        N = np.stack([np.zeros((nf, npnt)), cd * ny - sd * nz, sd * ny + cd * nz], axis=-1).reshape(-1, 3)
        d_tf = np.column_stack([np.ones(nf), rails[f"dy_{side}"], rails[f"dz_{side}"]])
        Rc_p = Rc[rep]
        Rb_inv_p = Rb_inv[rep]
        u = Rb_inv_p.apply(Oc[rep] + Rc_p.apply(P) - p[rep])
        d = Rb_inv_p.apply(Rc_p.apply(d_tf[rep]))
        n_b = Rb_inv_p.apply(Rc_p.apply(N))
        pl = cam.laser_plane
        lam = -(u @ pl[:3] + pl[3]) / (d @ pl[:3])
        X = u + lam[:, None] * d
        facing = np.einsum("ij,ij->i", n_b, cam.t_tgms_cam_m - X) > 0
        uu, vv, depth = project(cam, X)
        w, h = cam.image_size_px
        uu = uu + rng.normal(0, st.pixel_noise_px, len(uu))
        vv = vv + rng.normal(0, st.pixel_noise_px, len(vv))
        outl = rng.random(len(uu)) < st.outlier_fraction
        uu[outl] += rng.uniform(-40, 40, outl.sum())
        vv[outl] += rng.uniform(-40, 40, outl.sum())
        keep = facing & (depth > 0) & (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
        dropped = rng.random(nf) < st.dropout_fraction
        keep &= ~dropped[rep]
        no_face = rng.random(nf) < st.no_gauge_face_fraction
        keep &= ~(no_face[rep] & (np.tile(outline[:, 1], nf) > 0.006))
        out[side] = LaserPoints(frame=rep[keep], t_s=t_f[rep[keep]], u_px=uu[keep], v_px=vv[keep])
    return out


def simulate(settings: SimulationSettings = SimulationSettings()) -> tuple[Recording, Truth]:
    """A synthetic TGMS recording and its truth.

    Parameters
    ----------
    settings : SimulationSettings.

    Returns
    -------
    (Recording, Truth)
    """
    st = settings
    rng = np.random.default_rng(st.seed)
    alignment = design_alignment(st.length_m + 20.0)
    sc = _Scenario(st, alignment, rng)
    cams = default_cameras(st.half_rail_spacing_m, st.tgms_height_m, st.laser_plane_x_m)
    t_imu, s_imu, w, f = _imu(sc, st, rng)
    # camera frames
    t_f = np.arange(0.0, t_imu[-1], 1.0 / st.camera_rate_hz)
    s_f = np.interp(t_f, t_imu, s_imu)
    v_f = sc.speed(t_f)
    lasers = _laser_points(sc, st, cams, t_f, s_f, v_f, rng)
    # encoder: wheel rolling along the centre line, diameter off by wheel_scale_error; computed
    # after the cameras so that the optional drift's draws come last and leave the rest unchanged
    enc = EncoderSettings()
    if st.encoder_creep_s2_m == 0.0 and st.rolling_radius_rms == 0.0:
        # the constant-scale encoder exactly as before the drift options (bit-identical recordings)
        dist = s_imu - sc.s_start
    else:
        a_imu = np.gradient(sc.speed(t_imu), t_imu)
        eps = rolling_radius_variation(rng, s_imu, st.rolling_radius_rms, st.rolling_radius_corr_m)
        dist = encoder_distance(s_imu, a_imu, eps, st.encoder_creep_s2_m)
    counts = np.floor(dist / (enc.metres_per_count * (1 + st.wheel_scale_error))).astype(np.int64)
    config = TgmsConfig(track=TrackSettings(rail_profile=st.rail_profile,
                                            half_rail_spacing_m=st.half_rail_spacing_m,
                                            rail_inclination=st.rail_inclination,
                                            alignment="alignment.xml", start_station_m=sc.s_start),
                        encoder=enc, imu_rate_hz=st.imu_rate_hz, cameras=cams)
    rec = Recording(config=config, alignment=alignment, imu_t_s=t_imu, imu_w_rad_s=w, imu_f_m_s2=f,
                    enc_t_s=t_imu.copy(), enc_count=counts, lasers=lasers)
    # truth on a 0.05 m grid covering the ride
    s_g = np.arange(np.ceil(s_imu[0] / 0.05) * 0.05, s_imu[-1], 0.05)
    moving = np.concatenate([[True], np.diff(s_imu) > 0])
    t_g = np.interp(s_g, s_imu[moving], t_imu[moving])
    r = sc.rails(s_g)
    v_g = sc.speed(t_g)
    g = alignment.evaluate(s_g)
    a_lat = g.rho_h_1_m * v_g ** 2 - GRAVITY_M_S2 * np.sin(g.cant_rad)
    r_y, r_z, roll, pitch, yaw = sc.body_motion(t_g, s_g, v_g, a_lat)
    truth = Truth(s_m=s_g, gauge_variation_mm=units.m_to_mm(r["gv"]), cross_level_mm=units.m_to_mm(r["cl"]),
                  alignment_mm=units.m_to_mm(r["al"]), vertical_profile_mm=units.m_to_mm(r["vp"]),
                  t_s=t_g, r_y_m=r_y, r_z_m=r_z, roll_rad=roll, pitch_rad=pitch, yaw_rad=yaw)
    return rec, truth
