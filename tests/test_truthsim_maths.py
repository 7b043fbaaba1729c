"""Truth simulator building blocks: rotations, motion profile, Earth model, chunking, PSD."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import trolley.truthsim as ts
from trolley.earth import normal_gravity_m_s2, transport_rate_n
from test_truthsim_kinematics import BASE, small_alignment

angles = st.floats(-3.0, 3.0, allow_nan=False)
pitches = st.floats(-1.5, 1.5, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(angles, pitches, angles)
def test_quaternion_matches_scipy_zyx(roll, pitch, yaw):
    q = ts.quat_from_euler(np.array(roll), np.array(pitch), np.array(yaw))
    ref = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat(scalar_first=True)
    assert min(np.max(np.abs(q - ref)), np.max(np.abs(q + ref))) < 1e-14
    v = np.array([0.3, -1.2, 2.0])
    np.testing.assert_allclose(ts._quat_rotate(q, v),
                               Rotation.from_euler("ZYX", [yaw, pitch, roll]).apply(v), atol=1e-14)
    np.testing.assert_allclose(ts._dcm_from_euler(roll, pitch, yaw),
                               Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix(), atol=1e-15)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3), st.floats(1e-9, 3.0))
def test_rotvec_of_increment_matches_scipy(axis, angle):
    axis = np.asarray(axis)
    if np.linalg.norm(axis) < 1e-3:
        axis = np.array([0.0, 0.0, 1.0])
    rv = axis / np.linalg.norm(axis) * angle
    a = Rotation.from_euler("ZYX", [0.4, -0.1, 0.05])
    b = a * Rotation.from_rotvec(rv)
    qa, qb = a.as_quat(scalar_first=True), b.as_quat(scalar_first=True)
    got = ts._rotvec_from_quat(ts._quat_mul(ts._quat_conj(qa), qb))
    np.testing.assert_allclose(got, rv, rtol=1e-9, atol=1e-15)


@settings(max_examples=30, deadline=None)
@given(st.floats(5.0, 150.0), st.floats(0.3, 2.0), st.floats(1.0, 8.0), st.floats(0.0, 50.0))
def test_motion_profile_derivatives_and_stops(spacing, speed, accel_time, stop_s):
    m = ts.motion_profile(100.0, 2.5 * spacing, spacing, 7.0, stop_s, speed, accel_time)
    np.testing.assert_allclose(m.stop_chainage_m, 100.0 + spacing * np.array([0, 1, 2, 2.5]))
    t = np.sort(np.random.default_rng(0).uniform(0.0, m.duration_s, 3000))
    s, v, a = m.evaluate(t)
    assert np.all(np.diff(s) >= 0)
    assert np.max(v) <= speed * (1 + 1e-12)
    # v = ds/dt and a = dv/dt (central differences with a small step)
    h = 1e-5
    sp, vp, _ = m.evaluate(t + h)
    sm, vm, _ = m.evaluate(t - h)
    np.testing.assert_allclose((sp - sm) / (2 * h), v, atol=1e-7)
    np.testing.assert_allclose((vp - vm) / (2 * h), a, atol=1e-7)
    # standing at each stop for the stated time
    for k, (t0, t1) in enumerate(zip(m.stop_start_s, m.stop_end_s)):
        ss, vv, aa = m.evaluate(np.linspace(t0, t1, 7))
        np.testing.assert_allclose(ss, m.stop_chainage_m[k], atol=1e-9)
        assert np.all(np.abs(vv) < 1e-12) and np.all(np.abs(aa) < 1e-12)
    assert m.stop_end_s[0] == 7.0
    np.testing.assert_allclose(m.stop_end_s[1:] - m.stop_start_s[1:], stop_s, atol=1e-9)
    # each leg: d / v + T_a, with v lowered for short legs
    d = np.diff(m.stop_chainage_m)
    v_leg = np.minimum(speed, d / accel_time)
    np.testing.assert_allclose(m.stop_start_s[1:] - m.stop_end_s[:-1], d / v_leg + accel_time,
                               rtol=1e-12)


def test_normal_gravity_reference_values():
    # Somigliana (WGS-84): equator and pole values of the defining constants
    assert abs(normal_gravity_m_s2(0.0) - 9.7803253359) < 1e-10
    assert abs(normal_gravity_m_s2(np.pi / 2) - 9.8321849379) < 1e-9
    # free-air gradient about -3.086e-6 s^-2
    g = normal_gravity_m_s2(np.radians(45.0), np.array([0.0, 1000.0]))
    assert abs((g[1] - g[0]) / 1000.0 + 3.086e-6) < 5e-9


def test_transport_rate_hand_computed():
    # 1 m/s due east at 60 N, h = 0: w_en = [1/R, 0, -tan(60)/R]
    w = transport_rate_n(np.array([0.0, 1.0, 0.0]), np.radians(60.0))
    np.testing.assert_allclose(w, [1 / 6378137.0, 0.0, -np.sqrt(3) / 6378137.0], rtol=1e-12)


def test_chunking_does_not_change_the_result(monkeypatch):
    cfg = replace(BASE, length_m=60.0, static_s=5.0, stop_s=2.0)
    ref = ts.simulate_survey(small_alignment(), cfg)
    monkeypatch.setattr(ts, "_CHUNK", 977)
    got = ts.simulate_survey(small_alignment(), cfg)
    np.testing.assert_array_equal(got.session.imu_w_rad_s, ref.session.imu_w_rad_s)
    np.testing.assert_array_equal(got.session.imu_f_m_s2, ref.session.imu_f_m_s2)
    np.testing.assert_array_equal(got.truth.yaw_rad, ref.truth.yaw_rad)


def test_irregularity_spectrum_band():
    """The drawn irregularity's periodogram follows the stated PSD shape in and out of band."""
    rng = np.random.default_rng(1)
    n, step = 2 ** 16, 0.05
    x = ts._irregularities(rng, n, step, 1e-3, slice(0, n), count=4)
    f = np.fft.rfftfreq(n, step)
    win = np.hanning(n)[:, None]          # a window: the rectangular one leaks low-nu power
    p = np.mean(np.abs(np.fft.rfft(x * win, axis=0)) ** 2, axis=1)

    def band(lo, hi):
        m = (f >= lo) & (f < hi)
        return p[m].mean() / ts.irregularity_psd(f[m]).mean()

    mid = band(1 / 30, 1 / 10)
    assert 0.5 < band(1 / 100, 1 / 50) / mid < 2.0      # nu^-2 shape inside the band
    assert 0.5 < band(1 / 5, 1 / 3.5) / mid < 2.0
    # almost nothing below 1 m wavelength
    assert p[f > 1.0].sum() < 1e-6 * p.sum()
