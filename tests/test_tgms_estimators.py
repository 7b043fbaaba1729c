"""TGMS odometry (Escalona 2021 Eq. 40-43), relative attitude (Eq. 39, Briales Sec. 5.2),
relative trajectory (Eq. 46) and irregularity formulas (Eq. 24, 27)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from trolley.tgms.irregularities import irregularities, resample
from trolley.tgms.odometry import (correct_stations, correlation_samples, design_z_angle, fused_scale_error,
                                   heading_fit, match_curves, odometry, remap)
from trolley.tgms.orientation import _madgwick_gradient, attitude_kf, attitude_madgwick
from trolley.tgms.params import TgmsParams
from trolley.tgms.simulate import design_alignment
from trolley.tgms.track import GRAVITY_M_S2, TrackKinematics
from trolley.tgms.trajectory import trajectory_ltv


def test_remap_is_piecewise_linear_through_anchors():
    s_app = np.array([0.0, 50.0, 100.0, 150.0, 250.0])
    s, k = remap(s_app, np.array([0.0, 100.0]), np.array([0.0, 101.0]))
    assert s == pytest.approx([0.0, 50.5, 101.0, 151.5, 252.5])
    assert k == pytest.approx([1.01, 1.01, 1.01, 1.01, 1.01])


@settings(max_examples=15, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-2e-3, 2e-3))
def test_curvature_matching_finds_the_exit(shift_m, scale_err):
    al = design_alignment(200.0)
    s_true = np.arange(5.0, 215.0, 0.02)
    g = al.evaluate(s_true)
    # white noise of 5e-5 1/m per 2 cm sample: about 0.02 m of exit error after the 8 m smoothing
    rho = g.rho_h_1_m * np.cos(g.cant_rad) + np.random.default_rng(0).normal(0, 5e-5, len(s_true))
    s_app = 5.0 + shift_m + (s_true - 5.0) * (1 + scale_err)
    app, des, ne2 = match_curves(s_app, rho, al)
    assert des[0] == pytest.approx(170.0)
    # the exit within the encoder's stretch over the curve
    assert app[0] == pytest.approx(5.0 + shift_m + 165.0 * (1 + scale_err), abs=0.08 + 140 * abs(scale_err))
    assert ne2[0] < 0.05
    # four passes from a known start on this curvature: a few cm along the whole ride
    s, k, A, D, N = correct_stations(s_app - shift_m, rho, al, 5.0, passes=4)
    assert np.abs(s - s_true).max() < 0.08


@settings(max_examples=15, deadline=None)
@given(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.integers(0, 2 ** 16))
def test_entry_and_exit_shifts_are_recovered(d_entry, d_exit, seed):
    """Encoder stations off by d_entry over the first curve's entry window (20-80 m, ramp middle
    50 m) and by d_exit over its exit window (120-180 m, middle 150 m), linear in between: each
    ramp's window (Escalona Fig. 10, points 1 and 2) finds its own shift, and the re-mapping
    through them puts both anchors within 0.12 m. Noise: 5e-5 1/m white per 2 cm sample,
    ~0.03 m (1 sigma) per anchor after smoothing. (A stretch that changes inside a window moves
    its anchor by about the stretch change times a quarter of the ramp length.)"""
    al = design_alignment(200.0)
    s_true = np.arange(5.0, 215.0, 0.02)
    g = al.evaluate(s_true)
    rho = g.rho_h_1_m * np.cos(g.cant_rad) + np.random.default_rng(seed).normal(0, 5e-5, len(s_true))
    shift = np.interp(s_true, [5.0, 20.0, 80.0, 120.0, 180.0], [0.0, d_entry, d_entry, d_exit, d_exit])
    s_app = s_true + shift
    app, des, ne2 = match_curves(s_app, rho, al, windows="entry_exit")
    assert des.tolist() == [50.0, 150.0]
    assert app == pytest.approx(des + np.array([d_entry, d_exit]), abs=0.12)
    s, k, A, D, N = correct_stations(s_app, rho, al, 5.0, windows="entry_exit")
    # the re-mapped stations are right at both anchors (linear in between, Fig. 11)
    assert np.interp([50.0, 150.0], s_true, s) == pytest.approx([50.0, 150.0], abs=0.12)


@pytest.mark.parametrize("windows", ["curve", "entry_exit"])
def test_matching_is_unbiased_on_clean_curvature(windows):
    """No lag or half-cell offset: clean design curvature on shifted stations gives the shift to
    within a few mm (the separate entry/exit windows were suspected of a bias)."""
    al = design_alignment(200.0)
    s_true = np.arange(5.0, 215.0, 0.02)
    g = al.evaluate(s_true)
    rho = g.rho_h_1_m * np.cos(g.cant_rad)
    app, des, _ = match_curves(s_true + 0.37, rho, al, windows=windows)
    assert len(des) >= 1
    assert app - des == pytest.approx(np.full(len(des), 0.37), abs=0.005)


def test_matching_windows_are_validated():
    al = design_alignment(200.0)
    with pytest.raises(ValueError, match="windows"):
        match_curves(np.arange(0.0, 200.0, 0.1), np.zeros(2000), al, windows="exits")


def _heading_ride(k_true, bias, seed, noise_rad=1.5e-4, length_m=200.0):
    """A hand-built ride over the first curve of ``design_alignment``: the gyro z angle is the
    design z angle at the true stations plus a smooth random angle (the alignment irregularities
    and the vehicle's yaw: 1.5e-4 rad rms, ~3 m correlation) plus a rate offset; the encoder reads
    s_app = s0 + (s - s0) / (1 + k_true)."""
    from scipy.ndimage import gaussian_filter1d
    al = design_alignment(length_m)
    dt = 0.01
    t = np.arange(0.0, 40.0, dt)
    s0 = 5.0
    v = 6.0 * (1 + 0.1 * np.sin(2 * np.pi * t / 17.0)) * np.clip(t / 2.0, 0.0, 1.0)
    s = s0 + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
    keep = s < s0 + length_m
    t, s, v = t[keep], s[keep], v[keep]
    sg, psi_d, _ = design_z_angle(al, s0 - 1.0, s.max() + 1.0)
    rng = np.random.default_rng(seed)
    # smooth in time: a Gaussian of 50 samples (0.5 s, ~3 m at 6 m/s)
    n = gaussian_filter1d(rng.normal(0.0, 1.0, len(t)), 50.0)
    n *= noise_rad / n.std()
    psi = np.interp(s, sg, psi_d) + n + bias * t
    omega_z = np.gradient(psi, dt)
    s_app = s0 + (s - s0) / (1 + k_true)
    return al, t, s, v, omega_z, s_app, s0


@pytest.mark.parametrize("k_true, bias, seed", [(1e-3, 2e-5, 0), (-2e-3, -5e-5, 1), (0.0, 1e-4, 2), (3e-3, 0.0, 3)])
def test_heading_fit_recovers_a_known_encoder_scale(k_true, bias, seed):
    """The encoder scale error and the gyro offset are recovered within 3 of the fit's own sigmas,
    and the sigma is small enough to matter (a wrong model, e.g. the offset not fitted or the
    design angle taken at the wrong stations, misses by many sigmas)."""
    al, t, s, v, omega_z, s_app, s0 = _heading_ride(k_true, bias, seed)
    hf = heading_fit(t, omega_z, s_app, al, s0)
    assert 0 < hf.sigma_scale_error < 5e-4
    assert abs(hf.scale_error - k_true) < 3 * hf.sigma_scale_error
    assert hf.gyro_offset_rad_s == pytest.approx(bias, abs=2e-5)
    assert hf.correlation_samples > 10            # the smooth angle noise is seen as correlated


def test_heading_fit_is_exact_on_clean_data():
    al, t, s, v, omega_z, s_app, s0 = _heading_ride(1.5e-3, 3e-5, 0, noise_rad=0.0)
    hf = heading_fit(t, omega_z, s_app, al, s0)
    assert hf.scale_error == pytest.approx(1.5e-3, abs=2e-5)


def test_heading_fit_sigma_is_honest_over_many_rides():
    """The normalised errors (k - k_true) / sigma over 30 noisy rides have an rms near 1 (neither
    over- nor under-confident by more than a factor 1.6)."""
    z = []
    for seed in range(30):
        al, t, s, v, omega_z, s_app, s0 = _heading_ride(1e-3, 2e-5, 100 + seed)
        hf = heading_fit(t, omega_z, s_app, al, s0)
        z.append((hf.scale_error - 1e-3) / hf.sigma_scale_error)
    assert 1 / 1.6 < np.sqrt(np.mean(np.square(z))) < 1.6


def test_odometry_methods_give_the_true_stations():
    """The whole odometry on the hand-built ride: the fused and heading methods put the stations
    within 3 sigma of the scale error times the distance, and closer than the raw encoder."""
    k_true = 2e-3
    al, t, s, v, omega_z, s_app, s0 = _heading_ride(k_true, 2e-5, 7)
    counts = np.floor((s - s0) / 0.001).astype(np.int64)
    for method in ("fused", "heading"):
        o = odometry(t, t, counts, 0.001 / (1 + k_true), s0, omega_z, al, method=method)
        moving = v > 1.0
        err = np.abs(o.s_m - s)[moving]
        assert err.max() < 3 * o.sigma_scale_error * (s.max() - s0) + 0.01
        assert err.max() < 0.5 * np.abs(o.s_app_m - s)[moving].max()
    with pytest.raises(ValueError, match="method"):
        odometry(t, t, counts, 0.001, s0, omega_z, al, method="exits")


def test_heading_fit_on_a_straight_says_nothing():
    """A ride on the first straight only: no scale information, and the odometry keeps the encoder."""
    al, t, s, v, omega_z, s_app, s0 = _heading_ride(1e-3, 2e-5, 0, length_m=20.0)
    assert s.max() < 26.0
    hf = heading_fit(t, omega_z, s_app, al, s0)
    assert hf.scale_error == 0.0 and hf.sigma_scale_error == float("inf")
    counts = np.floor((s - s0) / 0.001).astype(np.int64)
    o = odometry(t, t, counts, 0.001, s0, omega_z, al)
    assert o.scale_error == 0.0
    assert o.s_m == pytest.approx(o.s_app_m)


def test_fused_scale_error_is_the_inverse_variance_mean():
    from trolley.tgms.odometry import HeadingFit
    hf = HeadingFit(scale_error=1e-3, sigma_scale_error=2e-4, gyro_offset_rad_s=0.0, residual_rms_rad=0.0,
                    correlation_samples=1.0)
    # an anchor 100 m from the start matched 0.3 m long: k = 3e-3 with 0.1 m / 100 m = 1e-3;
    # an anchor 5 m from the start carries no scale and is skipped
    k, sk = fused_scale_error(hf, np.array([5.0 + 100.0 / 1.003, 10.0]), np.array([105.0, 10.1]),
                              np.array([0.1, 0.1]), 5.0)
    w1, w2 = 1 / 2e-4 ** 2, (100.0 / 1.003 / 0.1) ** 2
    assert k == pytest.approx((w1 * 1e-3 + w2 * 3e-3) / (w1 + w2), rel=1e-6)
    assert sk == pytest.approx(1 / np.sqrt(w1 + w2), rel=1e-6)
    assert fused_scale_error(None, np.array([]), np.array([]), np.array([]), 5.0) == (0.0, float("inf"))


def test_correlation_samples():
    rng = np.random.default_rng(0)
    assert correlation_samples(rng.normal(size=20000)) == pytest.approx(1.0, abs=0.2)
    # a 10-sample moving average of white noise: integral correlation time 10 samples (summing the
    # sample autocorrelation to its first negative lag adds some of its noise: a little high)
    x = np.convolve(rng.normal(size=40000), np.ones(10) / 10, mode="valid")
    assert 9.0 < correlation_samples(x) < 13.0


def test_curvature_anchor_sigma_matches_its_scatter():
    """The Eq. 41 anchors' sigmas (with_sigma) agree with their scatter over noisy rides."""
    al = design_alignment(200.0)
    s_true = np.arange(5.0, 215.0, 0.02)
    g = al.evaluate(s_true)
    errs, sigs = [], []
    for seed in range(20):
        rho = g.rho_h_1_m * np.cos(g.cant_rad) + np.random.default_rng(seed).normal(0, 5e-4, len(s_true))
        app, des, ne2, sig = match_curves(s_true + 0.2, rho, al, with_sigma=True, max_ne2=1.0)
        errs.append(app[0] - des[0] - 0.2)
        sigs.append(sig[0])
    ratio = np.sqrt(np.mean(np.square(errs))) / np.median(sigs)
    assert 0.5 < ratio < 2.0


def _straight_kinematics(n, dt, v=10.0, delta=-0.45):
    t = np.arange(n) * dt
    z = np.zeros(n)
    return TrackKinematics(t_s=t, s_m=v * t, v_m_s=np.full(n, v), a_m_s2=z, rho_h=z, drho_h=z, rho_v=z,
                           rho_tw=z, heading_rad=z, slope_rad=z, cant_rad=z, omega_t=np.zeros((n, 3)),
                           alpha_t=np.zeros((n, 3)),
                           f_design=np.column_stack([z, z, np.full(n, -GRAVITY_M_S2)]))


def _body(n, dt, rng):
    """Relative roll/pitch and lateral/vertical motion of a TGMS on a straight track, with the
    IMU readings they produce (small-angle exact) plus white noise."""
    t = np.arange(n) * dt
    roll = 1e-3 * np.sin(2 * np.pi * 0.8 * t) + 5e-4 * np.sin(2 * np.pi * 0.23 * t + 1)
    pitch = 4e-4 * np.sin(2 * np.pi * 0.5 * t + 2)
    ry = 3e-3 * np.sin(2 * np.pi * 1.1 * t) + 2e-3 * np.sin(2 * np.pi * 0.4 * t + 0.5)
    rz = 2e-3 * np.sin(2 * np.pi * 1.7 * t + 1.0)
    w = np.column_stack([np.gradient(roll, dt), np.gradient(pitch, dt), np.zeros(n)])
    ay = -(2 * np.pi * 1.1) ** 2 * 3e-3 * np.sin(2 * np.pi * 1.1 * t) - (2 * np.pi * 0.4) ** 2 * 2e-3 * np.sin(2 * np.pi * 0.4 * t + 0.5)
    az = -(2 * np.pi * 1.7) ** 2 * 2e-3 * np.sin(2 * np.pi * 1.7 * t + 1.0)
    g = GRAVITY_M_S2
    # f = A^T (a - g): small angles, gravity [0, 0, g] in the level frame
    f = np.column_stack([g * pitch, ay - g * roll, az - g])
    w = w + rng.normal(0, 4.4e-5 / np.sqrt(dt), w.shape) + np.array([1e-5, -2e-5, 0])
    f = f + rng.normal(0, 6e-4 / np.sqrt(dt), f.shape)
    return roll, pitch, ry, rz, w, f


def test_attitude_kf_and_madgwick_track_the_relative_roll():
    dt, n = 0.01, 6000
    rng = np.random.default_rng(3)
    roll, pitch, ry, rz, w, f = _body(n, dt, rng)
    kin = _straight_kinematics(n, dt)
    kf = attitude_kf(kin, w, f)
    mg = attitude_madgwick(kin, w, f)
    mid = slice(1000, 5000)
    e_kf = (kf.roll_rad - roll)[mid]
    e_mg = (mg.roll_rad - roll)[mid]
    # gyro-dominated in the band: errors far below the 1 mrad motion, after the mean
    assert np.std(e_kf) < 1e-4 and np.std(e_mg) < 3e-4
    assert np.std((kf.pitch_rad - pitch)[mid]) < 2e-4
    # the filter sigma is conservative here (it carries the slowly observed gyro-bias uncertainty)
    assert np.std(e_kf) < np.median(kf.sigma_roll_rad[mid]) < 1e-3


@settings(max_examples=30, deadline=None)
@given(st.floats(-0.05, 0.05), st.floats(-0.05, 0.05), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0),
       st.floats(-10.5, -9.0))
def test_madgwick_gradient_matches_finite_differences(phi, theta, z0, z1, fz):
    """The gradient of J = |z - h(x)|^2 / 2 (Briales Eq. 42, h = [-f_z theta, f_z phi]) used by the
    gradient-descent attitude equals the central difference of J."""
    z = np.array([z0, z1])

    def J(x):
        e = z - np.array([-fz * x[1], fz * x[0]])
        return 0.5 * e @ e

    x = np.array([phi, theta])
    h = 1e-6
    fd = np.array([(J(x + h * d) - J(x - h * d)) / (2 * h) for d in np.eye(2)])
    g = _madgwick_gradient(x, z, fz)
    assert g == pytest.approx(fd, rel=1e-6, abs=1e-6)
    # a step against it lowers the objective: J is quadratic with Hessian f_z^2 I, so half the
    # distance to its minimum along the gradient (a fixed 1e-4 rad overshot a point already within
    # 6e-9 rad of the minimum)
    if np.hypot(*g) > 1e-9:
        assert J(x - 0.5 * g / fz**2) < J(x)


def test_madgwick_starts_from_the_window_mean_not_one_swayed_sample():
    """A body sway of 0.4 m/s^2 lateral acceleration (apparent roll 0.04 rad in one sample) at the
    start and end of a 60 s ride: the normalised step corrects at most beta = 3e-4 rad/s, so a
    start from one sample left a roll ramp over the whole ride (the cause of the 0.7-1.3 mm
    alignment errors); started from the 2 s mean the error stays at the KF's level."""
    dt, n = 0.01, 6000
    rng = np.random.default_rng(5)
    roll, pitch, ry, rz, w, f = _body(n, dt, rng)
    t = np.arange(n) * dt
    f[:, 1] += 0.4 * np.cos(2 * np.pi * 1.3 * t) + 0.3 * np.cos(2 * np.pi * 2.1 * t + 0.2)
    kin = _straight_kinematics(n, dt)
    mid = slice(500, n - 500)
    e_new = (attitude_madgwick(kin, w, f).roll_rad - roll)[mid]
    e_one = (attitude_madgwick(kin, w, f, init_window_s=dt).roll_rad - roll)[mid]
    e_kf = (attitude_kf(kin, w, f).roll_rad - roll)[mid]
    rms = lambda e: np.sqrt(np.mean(e ** 2))  # noqa: E731 (no accelerometer bias here: the mean counts)
    assert rms(e_one) > 1e-2
    assert rms(e_new) < 3e-4 and rms(e_new) < 2 * rms(e_kf) + 5e-5


def test_trajectory_ltv_recovers_lateral_and_vertical_motion():
    dt, n = 0.01, 6000
    rng = np.random.default_rng(4)
    roll, pitch, ry, rz, w, f = _body(n, dt, rng)
    kin = _straight_kinematics(n, dt)
    tr = trajectory_ltv(kin, f, roll, pitch, TgmsParams(cutoff_wavelength_m=100.0))
    from trolley.bands import bandpass_wavelength
    mid = slice(1000, 5000)
    step = 10.0 * dt                          # 10 m/s: the D1 band is 0.4-3.3 Hz
    for est, true in ((tr.dr_y_m, ry), (tr.dr_z_m, rz)):
        e = bandpass_wavelength(est - true, step, 3.0, 25.0)[mid]
        assert np.std(e) < 0.08 * np.std(bandpass_wavelength(true, step, 3.0, 25.0)[mid])
    # unfiltered, the error is the low-frequency drift the virtual measurements leave (< 1 mm)
    assert np.std((tr.dr_y_m - ry)[mid]) < 1e-3


def test_irregularity_formulas_signs_and_rotation():
    L = 0.7175
    # left rail 2 mm higher (smaller z), right rail 1 mm outwards, TGMS level and centred
    irr = irregularities(np.array([0.0]), np.array([-L]), np.array([0.448]), np.array([L + 0.001]),
                         np.array([0.450]), np.array([0.0]), np.array([0.0]), np.array([-0.449]), L)
    assert irr.gauge_variation_m[0] == pytest.approx(0.001)
    assert irr.cross_level_m[0] == pytest.approx(0.002)
    assert irr.alignment_m[0] == pytest.approx(0.0005)
    assert irr.vertical_profile_m[0] == pytest.approx(0.0, abs=1e-12)
    # a perfect track seen from a TGMS rolled by phi: the vision sees the rails rotated by -phi
    phi = 3e-3
    c, s = np.cos(phi), np.sin(phi)
    yl, zl = c * -L + s * 0.45, -s * -L + c * 0.45
    yr, zr = c * L + s * 0.45, -s * L + c * 0.45
    irr = irregularities(np.array([0.0]), np.array([yl]), np.array([zl]), np.array([yr]), np.array([zr]),
                         np.array([phi]), np.array([0.0]), np.array([-0.45]), L)
    for name in ("gauge_variation_m", "cross_level_m", "alignment_m", "vertical_profile_m"):
        assert abs(getattr(irr, name)[0]) < 2e-5


def test_resample_leaves_gaps_empty():
    s = np.arange(0.0, 10.0, 0.1)
    v = s.copy()
    v[40:60] = np.nan            # flagged frames between 4.0 and 5.9
    out = resample(s, v, np.arange(0.0, 10.0, 0.25), max_gap_m=0.5)
    grid = np.arange(0.0, 10.0, 0.25)
    gap = (grid > 3.9) & (grid < 6.0)
    assert np.isnan(out[gap]).all()
    assert np.allclose(out[~gap & (grid < 9.9)], grid[~gap & (grid < 9.9)])


def test_odometry_method_parameter_is_validated():
    assert TgmsParams().odometry_method == "fused"
    assert TgmsParams.from_dict({"odometry_method": "anchors"}).odometry_method == "anchors"
    with pytest.raises(ValueError, match="odometry_method"):
        TgmsParams.from_dict({"odometry_method": "exits"})
