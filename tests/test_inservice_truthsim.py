"""The in-service truth simulator (trolley.inservice.{contact,irregularity,vehicle}): contact laws
against their closed forms, the free wheelset and the rigid bogie against the kinematic
wavelengths, PSD realisations against the spectrum's integral, curving and sensor noise."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad

from trolley.inservice import contact as ct
from trolley.inservice import irregularity as irr
from trolley.inservice import vehicle as vh

C = ct.ContactParameters()


# --------------------------------------------------------------------------------- contact
def test_conicity_is_nominal_at_zero_shift_and_grows():
    assert ct.equivalent_conicity(0.0, C) == pytest.approx(C.conicity, rel=1e-15)
    assert ct.local_conicity(0.0, C) == pytest.approx(C.conicity, rel=1e-15)
    a = np.linspace(0.0, 9e-3, 50)
    assert np.all(np.diff(ct.equivalent_conicity(a, C)) > 0)
    # S1002/UIC60-like: 15-25 % above nominal at 3 mm
    assert 1.15 < ct.equivalent_conicity(3e-3, C) / C.conicity < 1.25


@given(st.floats(1e-5, 12e-3))
@settings(max_examples=30, deadline=None)
def test_equivalent_conicity_is_the_harmonic_linearisation(amplitude):
    """UIC 519: first Fourier coefficient of Delta r(A sin t) / 2A, by quadrature vs the closed form."""
    num = quad(lambda t: ct.rolling_radius_difference(amplitude * np.sin(t), C) / 2.0 * np.sin(t), 0.0,
               2 * np.pi)[0] / (np.pi * amplitude)
    assert num == pytest.approx(float(ct.equivalent_conicity(amplitude, C)), rel=1e-9)


def test_small_creep_is_kalker_linear():
    fx, fy = ct.creep_forces(1e-6, -2e-6, C.wheel_load_n, C)
    assert fx == pytest.approx(-C.f11 * 1e-6, rel=2e-3)
    assert fy == pytest.approx(C.f22 * 2e-6, rel=2e-3)


@given(st.floats(-0.05, 0.05), st.floats(-0.05, 0.05), st.floats(1e3, 2e5))
@settings(max_examples=60, deadline=None)
def test_creep_force_never_exceeds_friction_and_saturates(nux, nuy, load):
    fx, fy = ct.creep_forces(nux, nuy, load, C)
    assert np.hypot(fx, fy) <= C.mu * load * (1 + 1e-12)
    # beyond beta = 3 the force is exactly mu N, in the direction opposite the creepage
    big_x, big_y = ct.creep_forces(np.sign(nux or 1.0) * 0.5, 0.0, load, C)
    assert np.hypot(big_x, big_y) == pytest.approx(C.mu * load, rel=1e-12)
    assert big_x * np.sign(nux or 1.0) < 0


def test_saturation_is_monotone_and_continuous_at_beta_3():
    beta = np.linspace(0.0, 6.0, 601)
    f = ct.saturation_factor(beta, 1.0) * beta
    assert np.all(np.diff(f) >= -1e-15) and f[-1] == pytest.approx(1.0)
    assert ct.saturation_factor(3.0, 1.0) * 3.0 == pytest.approx(1.0, rel=1e-12)


def test_unloaded_wheel_transmits_nothing():
    assert ct.creep_forces(0.01, 0.01, -5.0, C) == (0.0, 0.0)


def test_flange_force_deadband():
    d = C.flange_clearance_m
    assert ct.flange_force(0.99 * d, C) == 0.0
    assert ct.flange_force(d + 1e-3, C) == pytest.approx(-C.flange_stiffness_n_m * 1e-3)
    assert ct.flange_force(-d - 1e-3, C) == pytest.approx(C.flange_stiffness_n_m * 1e-3)


# --------------------------------------------------------------------------------- kinematics
def test_free_wheelset_runs_at_klingels_wavelength():
    """Free wheelset at 5 m/s released at 0.5 mm: wavelength from zero crossings vs 2 pi sqrt(r0 b / lambda)."""
    s, y = vh.free_wheelset(C, 1813.0, 1120.0, 5.0, 0.5e-3, 30.0, step_m=0.05)
    i = np.where(np.sign(y[:-1]) != np.sign(y[1:]))[0]
    zc = s[i] - y[i] * (s[i + 1] - s[i]) / (y[i + 1] - y[i])
    assert len(zc) >= 4
    assert 2 * np.mean(np.diff(zc)) == pytest.approx(vh.kinematic_wavelength(C), rel=0.01)


def test_rigid_bogie_mode_has_the_rigid_truck_kinematic_wavelength():
    """Primary suspension 100x stiffer, secondary almost free, 2 m/s: the bogie hunting mode's
    wavelength is Wickens' rigid-truck 2 pi sqrt(r0 b / lambda (1 + f22 a^2 / (f11 b^2)))."""
    p = vh.VehicleParameters(kx_p=3.1391e9, ky_p=3.884e8, kx_s=1e3, ky_s=1e3, cy_s=0.0, k_antiroll=0.0)
    m = [m for m in vh.modes(p, 2.0) if m.bogie_share > 0.5 and m.lateral_share > 0.5][0]
    a, b = p.a_wheelset, p.b
    want = 2 * np.pi * np.sqrt(p.r0 * b / p.conicity * (1 + p.f22 * a ** 2 / (p.f11 * b ** 2)))
    assert m.wavelength_m == pytest.approx(want, rel=0.01)


def test_vehicle_is_stable_at_the_paper_speed_and_first_bogie_mode():
    p = vh.VehicleParameters()
    a = vh._System(p, 20.0, 0.0).jacobian()
    assert np.max(np.linalg.eigvals(a).real) < 0
    m = vh.first_lateral_mode(p, 20.0)
    assert m.wavelength_m == pytest.approx(20.0 / m.frequency_hz)
    assert 1.0 < m.frequency_hz < 1.5  # paper: 1.277 Hz for the ML95


# --------------------------------------------------------------------------------- irregularities
@pytest.mark.parametrize("kind", ["alignment", "vertical", "cross_level_angle"])
def test_psd_realisation_variance_is_the_psd_integral(kind):
    from trolley.tgms.simulate import irregularity_psd
    s = np.arange(0.0, 3000.0, 0.1)
    x = irr.psd_realisation(kind, s, np.random.default_rng(3))
    om = 2 * np.pi * np.fft.rfftfreq(len(s), 0.1)
    keep = (om >= 2 * np.pi / 300.0) & (om <= 2 * np.pi / 1.0) & (om > 0)
    riemann = np.sum(irregularity_psd(kind, om[keep]) * om[1])
    assert np.mean(x ** 2) == pytest.approx(riemann, rel=1e-10)
    assert np.mean(x ** 2) == pytest.approx(irr.psd_band_variance(kind, 0.1), rel=0.05)


def test_irregularity_lead_in_ramp_and_plus():
    a = irr.irregularity_from_psd(100.0, seed=1, lead_in_m=40.0)
    h = irr.harmonic_irregularity(100.0, 15.0, 1e-3, lead_in_m=40.0)
    assert a.lateral_m[0] == 0.0 and a.vertical_m[0] == 0.0 and h.lateral_m[0] == 0.0
    s0 = np.searchsorted(a.s_m, 0.0)
    assert h.lateral_m[s0 + 37] == pytest.approx(1e-3 * np.sin(2 * np.pi * a.s_m[s0 + 37] / 15.0))
    both = a.plus(h)
    assert np.allclose(both.lateral_m, a.lateral_m + h.lateral_m)
    lat, _, _ = both.at(a.s_m[500:510])
    assert np.allclose(lat, both.lateral_m[500:510], atol=1e-12)
    with pytest.raises(ValueError, match="grids differ"):
        a.plus(irr.harmonic_irregularity(50.0, 15.0, 1e-3, lead_in_m=40.0))


# --------------------------------------------------------------------------------- runs
@pytest.fixture(scope="module")
def short_runs():
    track = irr.irregularity_from_psd(60.0, seed=2, lead_in_m=40.0)
    p = vh.VehicleParameters()
    return (vh.simulate_run(p, track, 20.0, 60.0, sensor_noise=True, seed=7),
            vh.simulate_run(p, track, 20.0, 60.0, sensor_noise=False, seed=7))


def test_sensor_noise_has_the_specified_std(short_runs):
    noisy, clean = short_runs
    n = len(noisy.t_s)
    assert n == 601 and noisy.t_s[1] == pytest.approx(0.005) and noisy.s_m[-1] == pytest.approx(60.0)
    tol = 4.0 / np.sqrt(2 * n)
    for ch, sig in (("wheelset_ay_m_s2", 0.01), ("frame_ay_m_s2", 0.01), ("wheelset_wz_rad_s", 5e-4)):
        d = getattr(noisy, ch) - getattr(clean, ch)
        assert np.std(d) == pytest.approx(sig, rel=tol)
        assert abs(np.mean(d)) < 4 * sig / np.sqrt(n)
    assert clean.sigma_acc_m_s2 == 0.0 and noisy.sigma_gyro_rad_s == 5e-4


def test_run_channels_are_consistent_with_the_states(short_runs):
    """Gyro = yaw rate of the leading wheelset; the wheelset follows the alignment within the flangeway;
    the lateral acceleration integrates to the lateral velocity (trapezoid, to 1 %)."""
    _, r = short_runs
    assert np.array_equal(r.wheelset_wz_rad_s, r.wheelset_wz_rad_s_true)
    assert np.max(np.abs(r.wheelset_y_m - r.alignment_m)) < 9.1e-3
    assert np.corrcoef(r.wheelset_y_m, r.alignment_m)[0, 1] > 0.8
    from scipy.integrate import cumulative_trapezoid
    v = r.wheelset_vy_m_s[0] + cumulative_trapezoid(r.wheelset_ay_true_m_s2, r.t_s, initial=0.0)
    assert np.max(np.abs(v - r.wheelset_vy_m_s)) < 0.01 * np.max(np.abs(r.wheelset_vy_m_s))


def test_curve_steady_state():
    """Perfect left curve R = 1000 m at 20 m/s: the sensors read V^2 kappa and V kappa, the leading
    wheelset runs outwards (to the right), further than the trailing one of its bogie and further than
    a free wheelset would (r0 b kappa / lambda: the stiff primary yaw keeps the axles parallel)."""
    kappa = 1e-3
    track = irr.irregularity_from_psd(30.0, lead_in_m=40.0, lateral_scale=0.0, vertical_scale=0.0)
    r = vh.simulate_run(vh.VehicleParameters(), track, 20.0, 30.0, sensor_noise=False, curvature_1_m=kappa)
    assert np.allclose(r.wheelset_ay_m_s2, 400.0 * kappa, atol=1e-6)
    assert np.allclose(r.frame_ay_m_s2, 400.0 * kappa, atol=1e-6)
    assert np.allclose(r.wheelset_wz_rad_s, 20.0 * kappa, atol=1e-8)
    assert r.wheelset_y_m[0] < -C.r0 * C.b * kappa / C.conicity < 0.0
    assert np.allclose(r.wheelset_y_m, r.wheelset_y_m[0], atol=1e-9)
    sysm = vh._System(vh.VehicleParameters(), 20.0, kappa)
    q = sysm.equilibrium()
    assert q[0] == pytest.approx(r.wheelset_y_m[0], abs=1e-9) and q[0] < q[1] < 0.0


def test_rigid_vehicle_motions_load_no_suspension():
    """The assembled Jacobians: moving the whole car sideways, or yawing it about its centre
    (y_k = eps x_k, psi = eps), or lifting the sprung bodies with the wheelset inputs deflects no
    element; rolling the body alone does (the anti-roll bars and springs)."""
    p = vh.VehicleParameters()
    lin = vh._assemble(p, 0.0)
    bx = vh._bodies(p).x
    lateral = np.zeros(vh.N_DOF)
    yaw = np.zeros(vh.N_DOF)
    for body in range(7):
        base = body if body < 4 else (vh._frame_dof(body - 4, 0) if body < 6 else vh._BODY)
        lateral[base] = 1.0
        yaw[base] = bx[body]
        yaw[4 + body if body < 4 else base + 1] = 1.0
    bounce = np.zeros(vh.N_DOF)
    for base in (vh._frame_dof(0, 0), vh._frame_dof(1, 0), vh._BODY):
        bounce[base + 3] = 1.0
    u = np.concatenate([np.ones(4), np.zeros(4)])
    for q, uu in ((lateral, 0 * u), (yaw, 0 * u), (bounce, u)):
        assert np.max(np.abs(lin.j @ q + lin.ju @ uu)) < 1e-12
    roll = np.zeros(vh.N_DOF)
    roll[vh._BODY + 2] = 1.0
    assert np.max(np.abs(lin.j @ roll)) > 0.5
    k = lin.kc[:, :vh.N_DOF]
    assert np.allclose(k, k.T)


def test_robustness_factors_change_the_truth_not_the_nominal():
    """conicity -10 % / Kalker 50 % act on the simulated vehicle only: the nominal values the
    estimator gets stay, the truth's free-wheelset wavelength grows by 1 / sqrt(0.9) and the
    bogie mode moves."""
    p0 = vh.VehicleParameters()
    p1 = vh.with_factors(p0, conicity_factor=0.9, creep_factor=0.5)
    assert p1.nominal() == p0.nominal()
    assert vh.kinematic_wavelength(p1.contact) == pytest.approx(vh.kinematic_wavelength(p0.contact) / np.sqrt(0.9))
    f0 = vh.first_lateral_mode(p0, 20.0).frequency_hz
    assert abs(vh.first_lateral_mode(p1, 20.0).frequency_hz - f0) > 0.02
    fx0, _ = ct.creep_forces(1e-6, 0.0, C.wheel_load_n, C)
    fx1, _ = ct.creep_forces(1e-6, 0.0, C.wheel_load_n, C, creep_factor=0.5)
    assert fx1 == pytest.approx(0.5 * fx0, rel=1e-3)


@pytest.mark.parametrize("conicity_factor,creep_factor,speed,low,high", [
    (1.0, 1.0, 10.0, 0.63, 0.75), (0.9, 1.0, 20.0, 1.0, 1.26), (1.0, 0.5, 20.0, 0.9, 1.26),
    (0.9, 0.5, 20.0, 0.9, 1.26), (1.0, 1.0, 40.0, 2.0, 3.0)])
def test_first_lateral_mode_tracks_the_bogie_not_a_body_or_primary_mode(conicity_factor, creep_factor, speed,
                                                                      low, high):
    """The kinematic bogie frequency scales roughly with V sqrt(lambda): the selected mode stays in its
    window (the car body modes are at 0.63-0.88 Hz at any speed, the primary-suspension ones above 6 Hz)."""
    p = vh.with_factors(vh.VehicleParameters(), conicity_factor, creep_factor)
    assert low < vh.first_lateral_mode(p, speed).frequency_hz < high
