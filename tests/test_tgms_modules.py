"""TGMS modules against closed forms: track preprocessor (Escalona 2021 Eq. 2-5, Briales Eq. 18),
the 12-state smoother's Jacobian and motion recovery (Gonzalez-Carbajal 2023 Appendix 1), the
exact laser-plane transform against Eq. 23, CML budget and search box (Sec. 4.2, Eq. 17)."""
from __future__ import annotations


import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from trolley.alignment import Alignment, Arc, CantProfile, HorizontalAlignment, VerticalProfile
from trolley.tgms.ekf import measurement, measurement_jacobian, trajectory_ekf
from trolley.tgms.irregularities import irregularities, rails_in_laser_track_frame
from trolley.tgms.params import TgmsParams
from trolley.tgms.track import GRAVITY_M_S2, track_kinematics, track_rotation
from trolley.tgms.tuning import PAPER_FORM, search_box


def _canted_arc(radius_m: float, cant_rad: float) -> Alignment:
    hz = HorizontalAlignment.from_elements(0.0, 0.0, 0.3, [Arc(600.0, 1.0 / radius_m)])
    vp = VerticalProfile.from_pvis(np.array([0.0, 600.0]), np.array([100.0, 100.0]), np.array([0.0, 0.0]))
    cp = CantProfile.from_stations(np.array([0.0, 600.0]), np.array([cant_rad, cant_rad]))
    return Alignment(hz, vp, cp, name="arc")


@settings(max_examples=12, deadline=None)
@given(st.sampled_from([300.0, 500.0, -400.0]), st.floats(-0.1, 0.1), st.floats(3.0, 30.0), st.floats(-0.6, -0.3))
def test_track_kinematics_on_a_constant_canted_curve(radius, cant, v, delta):
    """On a level arc of curvature rho with constant cant phi at speed V the TF turns about the
    vertical at psi' = V rho: omega^t = psi' [0, sin phi, cos phi] (Eq. 5), and the point r0 =
    [0, 0, delta] fixed in the TF has the horizontal acceleration psi'^2 (R - e) towards the centre,
    e = -delta sin phi its lateral offset, so f^d = [0, a c - g s, -a s - g c] (Briales Eq. 18)."""
    al = _canted_arc(radius, cant)
    dt = 0.01
    t = np.arange(0.0, 8.0, dt)
    s = 100.0 + v * t
    kin = track_kinematics(al, t, s, np.array([0.0, 0.0, delta]))
    rho = 1.0 / radius
    psi_d = v * rho
    c, sn = np.cos(cant), np.sin(cant)
    a = v * v * rho + psi_d ** 2 * sn * delta
    mid = slice(5, -5)
    assert kin.omega_t[mid] == pytest.approx(np.tile([0.0, psi_d * sn, psi_d * c], (len(t) - 10, 1)), abs=1e-9)
    f_exp = np.array([0.0, a * c - GRAVITY_M_S2 * sn, -a * sn - GRAVITY_M_S2 * c])
    assert kin.f_design[mid] == pytest.approx(np.tile(f_exp, (len(t) - 10, 1)), abs=2e-6)
    assert kin.alpha_t[mid] == pytest.approx(np.zeros((len(t) - 10, 3)), abs=1e-8)


def _ekf_point(rng):
    x = np.concatenate([rng.normal(0, 0.05, 6), rng.normal(0, 0.01, 6)])
    Ct = track_rotation(np.array([0.4]), np.array([0.01]), np.array([0.05])).as_matrix()[0]
    fd = np.array([0.1, 0.5, -9.7])
    w_t = rng.normal(0, 0.02, 3)
    al_t = rng.normal(0, 0.01, 3)
    return x, Ct, fd, w_t, al_t


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ekf_jacobian_against_closed_forms_and_finer_differences(seed):
    x, Ct, fd, w_t, al_t = _ekf_point(np.random.default_rng(seed))
    h0, J = measurement_jacobian(x, Ct, fd, w_t, al_t)
    assert h0 == pytest.approx(measurement(x[None, :], Ct, fd, w_t, al_t)[0])
    phi, dphi, th, dth, psi, dpsi = x[:6]
    sp, cp, st_, ct = np.sin(phi), np.cos(phi), np.sin(th), np.cos(th)
    # gyro rows (Eq. 7): gx = phi' - sin(theta) psi', gy = cos(phi) theta' + sin(phi) cos(theta) psi',
    # gz = -sin(phi) theta' + cos(phi) cos(theta) psi'
    J_gyro = np.zeros((3, 12))
    J_gyro[0, [1, 2, 5]] = [1.0, -ct * dpsi, -st_]
    J_gyro[1, [0, 2, 3, 5]] = [-sp * dth + cp * ct * dpsi, -sp * st_ * dpsi, cp, sp * ct]
    J_gyro[2, [0, 2, 3, 5]] = [-cp * dth - sp * ct * dpsi, -cp * st_ * dpsi, -sp, cp * ct]
    assert J[:3] == pytest.approx(J_gyro, abs=1e-8)
    # accelerometer rows against r'' (Eq. 11: f = A^T (f^d + r'' + ...)): columns of A^{t,b}^T
    x2 = x.copy()                      # h is linear in r'': one unit step is exact
    x2[8] += 1.0
    d = measurement(x2[None, :], Ct, fd, w_t, al_t)[0] - h0
    assert J[3:6, 8] == pytest.approx(d[3:6], abs=1e-7)
    # virtual positions
    assert J[6, 6] == pytest.approx(1.0) and J[7, 9] == pytest.approx(1.0)
    # everything (incl. the angle derivatives of the accelerometer rows) against 10x finer steps
    from trolley.tgms.ekf import JACOBIAN_STEPS
    _, J_fine = measurement_jacobian(x, Ct, fd, w_t, al_t, JACOBIAN_STEPS / 10)
    assert J == pytest.approx(J_fine, rel=1e-5, abs=1e-6)


def test_ekf_recovers_a_synthetic_motion():
    """Straight level track at 10 m/s, a TGMS rolling, pitching, swaying and bouncing (IMU from the
    exact small-angle kinematics plus MEMS noise): the 12-state smoother recovers the relative
    roll to < 0.15 mrad and the 3-25 m band of r_y, r_z to < 10 % of the motion."""
    from tests.test_tgms_estimators import _body, _straight_kinematics
    from trolley.bands import bandpass_wavelength
    dt, n = 0.01, 4000
    roll, pitch, ry, rz, w, f = _body(n, dt, np.random.default_rng(5))
    kin = _straight_kinematics(n, dt)
    tr = trajectory_ekf(kin, w, f, None, TgmsParams(trajectory="ekf"))
    mid = slice(800, 3200)
    e_roll = (tr.attitude.roll_rad - roll)[mid]
    assert np.std(e_roll) < 1.5e-4
    step = 10.0 * dt
    for est, true in ((tr.dr_y_m, ry), (tr.dr_z_m, rz)):
        e = bandpass_wavelength(est - true, step, 3.0, 25.0)[mid]
        assert np.std(e) < 0.1 * np.std(bandpass_wavelength(true, step, 3.0, 25.0)[mid])


@settings(max_examples=30, deadline=None)
@given(st.floats(-3e-3, 3e-3), st.floats(-2e-3, 2e-3), st.floats(-2e-3, 2e-3), st.floats(-0.01, 0.01),
       st.floats(-0.01, 0.01), st.floats(20.0, 580.0))
def test_laser_frame_transform_reduces_to_eq23_when_x_is_zero(roll, pitch, yaw, ry, dz, s):
    """With the laser plane through the IMU (x_L = 0, s_L = s) the exact transform gives the
    irregularities of Eq. 24 and 27 (small-angle matrix of Eq. 23) up to second-order terms."""
    al = _canted_arc(500.0, 0.05)
    L = 0.7175
    u_l = np.array([[0.0, -L + 0.001, 0.45 + dz]])
    u_r = np.array([[0.0, L - 0.0005, 0.452]])
    rz = -0.45
    one = lambda v: np.array([v])
    ql, qr = rails_in_laser_track_frame(al, one(s), one(s), one(roll), one(pitch), one(yaw), one(ry), one(rz), u_l, u_r)
    irr = irregularities(one(s), u_l[:, 1], u_l[:, 2], u_r[:, 1], u_r[:, 2], one(roll), one(ry), one(rz), L)
    # second order: angle^2 times lever arms below 1 m -> < 3e-5 m for these ranges
    assert qr[0, 1] - ql[0, 1] - 2 * L == pytest.approx(irr.gauge_variation_m[0], abs=3e-5)
    assert qr[0, 2] - ql[0, 2] == pytest.approx(irr.cross_level_m[0], abs=3e-5)
    assert 0.5 * (ql[0, 1] + qr[0, 1]) == pytest.approx(irr.alignment_m[0], abs=3e-5)
    assert -0.5 * (ql[0, 2] + qr[0, 2]) == pytest.approx(irr.vertical_profile_m[0], abs=3e-5)
    # and with the TGMS level and centred the transform is the identity plus r
    ql0, _ = rails_in_laser_track_frame(al, one(s), one(s), one(0.0), one(0.0), one(0.0), one(ry), one(rz), u_l, u_r)
    assert ql0[0] == pytest.approx(u_l[0] + [0.0, ry, rz], abs=1e-9)


def test_absolute_search_box_is_eq17_in_the_paper_parameterisation():
    p = TgmsParams()
    names = ("gyro_noise_rad_sqrt_s", "accel_disturbance_m_s2", "ekf_u_pos_m2")
    box = search_box(names, p, "absolute")
    dt = 1.0 / p.process_rate_hz
    for name, (lo, hi) in zip(names, box):
        power, per_sample = PAPER_FORM[name]
        # the paper's p at both ends of the box: 1e-4 and 1e4
        assert (10 ** lo) ** power / dt ** per_sample == pytest.approx(1e-4)
        assert (10 ** hi) ** power / dt ** per_sample == pytest.approx(1e4)
    rel = search_box(names, p, "relative", decades=4.0)
    assert rel[0] == pytest.approx((np.log10(4.4e-5) - 4, np.log10(4.4e-5) + 4))
    with pytest.raises(ValueError, match="box"):
        search_box(names, p, "wide")


def test_the_search_never_returns_worse_than_the_defaults_outside_its_box():
    # a negative log-likelihood whose minimum is the defaults (log10 g = -4.357), outside a box
    # [-3, -1]: the box's best (its edge -3) is worse, so the defaults come back with their value;
    # inside a box that holds them, the search moves to a better point than the defaults
    from trolley.tgms.tuning import _maximise

    p = TgmsParams()
    names = ("gyro_noise_rad_sqrt_s",)
    xd = np.log10(p.gyro_noise_rad_sqrt_s)
    best, f, n, f_default = _maximise(lambda x: (x[0] - xd) ** 2, names, p, [(-3.0, -1.0)], 30, 0)
    assert best == p and f == f_default == 0.0 and n <= 30
    best, f, n, f_default = _maximise(lambda x: (x[0] + 4.0) ** 2, names, p, [(-6.0, -2.0)], 40, 0)
    assert f_default == pytest.approx((xd + 4.0) ** 2) and f < 1e-3 < f_default
    assert np.log10(best.gyro_noise_rad_sqrt_s) == pytest.approx(-4.0, abs=0.05)


def test_ltv_constraint_is_eq19():
    """u^ac <= u^pos / 10 with u^pos = u^ac / omega_c^4: omega_c = 2 pi V / cutoff <= 10^-1/4."""
    from trolley.tgms.tuning import satisfies_constraint
    v = 10.0
    limit = 2 * np.pi * v / 10 ** -0.25                  # shortest allowed cut-off wavelength, 111.7 m
    assert satisfies_constraint(TgmsParams(cutoff_wavelength_m=limit * 1.01), "ltv", v)
    assert not satisfies_constraint(TgmsParams(cutoff_wavelength_m=limit * 0.99), "ltv", v)
