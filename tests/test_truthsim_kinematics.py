"""Truth simulator: the synthesized IMU/odometer/fixes agree with the truth by independent methods.

The checks re-integrate the sensor data with code written only for these tests (scipy's
Rotation, a series normal-gravity formula, chord sums), never with the simulator's helpers.
"""
from __future__ import annotations

from pathlib import Path

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from trolley.alignment import (Alignment, Arc, CantProfile, Clothoid, HorizontalAlignment, Line,
                               VerticalProfile)
from trolley.landxml import parse_landxml
from trolley.session import TrolleyGeometry
from trolley.truthsim import SimulationConfig, motion_profile, simulate_survey

W_EARTH = 7.292115e-5
R_EARTH = 6378137.0


def small_alignment() -> Alignment:
    """200 m of tight design: straight, 300 m-radius curve with transitions, grades, cant."""
    h = HorizontalAlignment.from_elements(
        600000.0, 3300000.0, 0.7,
        [Line(30.0), Clothoid(40.0, 0.0, 1 / 300), Arc(60.0, 1 / 300), Clothoid(40.0, 1 / 300, 0.0),
         Line(60.0)], start_chainage_m=1000.0)
    v = VerticalProfile.from_pvis([1000.0, 1100.0, 1230.0], [20.0, 21.5, 20.85], [0.0, 40.0, 0.0])
    c = CantProfile.from_stations([1030.0, 1070.0, 1130.0, 1170.0], [0.0, 0.08, 0.08, 0.0])
    return Alignment(h, v, c)


MOUNT = np.array([0.01, -0.02, 0.03])
BASE = SimulationConfig(length_m=200.0, static_s=20.0, stop_s=10.0, imu_rate_hz=100.0,
                        odometer_rate_hz=100.0, irregularity_rms_m=0.0008, seed=3,
                        trolley=TrolleyGeometry(imu_misalignment_rad=MOUNT))


@pytest.fixture(scope="module")
def clean():
    """Errors off (irregularities kept), nominal mounting MOUNT known exactly."""
    return simulate_survey(small_alignment(), replace(BASE, errors=False))


@pytest.fixture(scope="module")
def noisy():
    return simulate_survey(small_alignment(), BASE)


def _truth_rotation(tr, idx) -> Rotation:
    return Rotation.from_euler("ZYX", np.column_stack([tr.yaw_rad[idx], tr.pitch_rad[idx],
                                                       tr.roll_rad[idx]]))


def _w_in_n(lat, v_n, h):
    """Earth rate + transport rate in NED (written out here, independent of trolley.earth)."""
    r = R_EARTH + h
    return np.array([W_EARTH * np.cos(lat) + v_n[1] / r, -v_n[0] / r,
                     -W_EARTH * np.sin(lat) - v_n[1] * np.tan(lat) / r])


def _gravity(lat, h):
    """GRS80 normal gravity, series form, with the linear free-air gradient."""
    return 9.780327 * (1 + 0.0053024 * np.sin(lat) ** 2 - 0.0000058 * np.sin(2 * lat) ** 2) \
        - 3.086e-6 * h


def _clip(sim, seconds=20.0):
    """IMU indices of a clip starting 2 s before the 2nd leg (standstill, then curve motion)."""
    rate = sim.config.imu_rate_hz
    t0 = sim.truth.motion.leg_start_s[1] - 2.0
    i0 = int(round(t0 * rate)) - 1          # imu_t_s[i] = (i + 1) / rate
    return i0, i0 + int(seconds * rate)


def test_gyros_reintegrate_to_truth_attitude(clean):
    """A plain quaternion loop over the gyro data reproduces the truth attitude to < 1e-6 rad."""
    tr, ses, cfg = clean.truth, clean.session, clean.config
    dt = 1.0 / cfg.imu_rate_hz
    i0, i1 = _clip(clean)
    mount = Rotation.from_euler("ZYX", MOUNT[::-1])
    lat0 = cfg.latitude_rad
    n0 = tr.N_m[0]
    c = _truth_rotation(tr, i0) * mount
    worst = 0.0
    moved = 0.0
    for k in range(i0 + 1, i1 + 1):
        v_n = np.array([tr.N_m[k] - tr.N_m[k - 1], tr.E_m[k] - tr.E_m[k - 1],
                        -(tr.H_m[k] - tr.H_m[k - 1])]) / dt
        h = 0.5 * (tr.H_m[k] + tr.H_m[k - 1])
        lat = lat0 + (0.5 * (tr.N_m[k] + tr.N_m[k - 1]) - n0) / (R_EARTH + h)
        w_nb = ses.imu_w_rad_s[k] - c.inv().apply(_w_in_n(lat, v_n, h))
        c = c * Rotation.from_rotvec(w_nb * dt)
        err = ((_truth_rotation(tr, k) * mount).inv() * c).magnitude()
        worst = max(worst, err)
        moved = max(moved, (_truth_rotation(tr, i0).inv() * _truth_rotation(tr, k)).magnitude())
    assert moved > 5e-3          # the clip really turns
    assert worst < 1e-6


def test_accelerometers_reintegrate_to_truth_velocity(clean):
    """Velocity from f^b (navigation equation, independent code) matches the truth motion."""
    tr, ses, cfg = clean.truth, clean.session, clean.config
    dt = 1.0 / cfg.imu_rate_hz
    i0, i1 = _clip(clean)
    mount = Rotation.from_euler("ZYX", MOUNT[::-1])
    n0 = tr.N_m[0]

    def pos(k):
        return np.array([tr.N_m[k], tr.E_m[k], -tr.H_m[k]])

    v = (pos(i0 + 1) - pos(i0 - 1)) / (2 * dt)
    assert np.linalg.norm(v) < 1e-9          # the clip starts at a standstill
    for k in range(i0 + 1, i1 + 1):
        ca, cb = _truth_rotation(tr, k - 1) * mount, _truth_rotation(tr, k) * mount
        c_mid = ca * Rotation.from_rotvec(0.5 * (ca.inv() * cb).as_rotvec())
        h = 0.5 * (tr.H_m[k] + tr.H_m[k - 1])
        lat = cfg.latitude_rad + (0.5 * (tr.N_m[k] + tr.N_m[k - 1]) - n0) / (R_EARTH + h)
        v_mid = (pos(k) - pos(k - 1)) / dt
        w_ie = W_EARTH * np.array([np.cos(lat), 0.0, -np.sin(lat)])
        w_en = _w_in_n(lat, v_mid, h) - w_ie
        acc = c_mid.apply(ses.imu_f_m_s2[k]) + np.array([0.0, 0.0, _gravity(lat, h)]) \
            - np.cross(2 * w_ie + w_en, v_mid)
        v = v + acc * dt
    v_truth = (pos(i1 + 1) - pos(i1 - 1)) / (2 * dt)
    assert np.linalg.norm(v_truth) > 0.5
    assert np.max(np.abs(v - v_truth)) < 5e-5


def test_static_specific_force_is_gravity(clean):
    tr, ses, cfg = clean.truth, clean.session, clean.config
    static = ses.imu_t_s < cfg.static_s - 1.0
    g = np.linalg.norm(ses.imu_f_m_s2[static], axis=1)
    expected = _gravity(cfg.latitude_rad, tr.H_m[static])
    assert np.max(np.abs(g - expected)) < 5e-6
    # and the gyros see only the Earth rate
    w = np.linalg.norm(ses.imu_w_rad_s[static], axis=1)
    assert np.max(np.abs(w - W_EARTH)) < 1e-12


def test_odometer_is_3d_path_length(clean):
    """Errors off: odometer = chord sum of the truth path, within one encoder count."""
    tr, ses, cfg = clean.truth, clean.session, clean.config
    assert cfg.imu_rate_hz == cfg.odometer_rate_hz
    p = np.column_stack([tr.E_m, tr.N_m, tr.H_m])
    path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    odo = ses.odo_distance_m[1:]               # odo_t_s[j] = j / rate, imu_t_s[i] = (i+1) / rate
    np.testing.assert_array_equal(ses.odo_t_s[1:], ses.imu_t_s)
    diff = path - (odo - odo[0])
    res = cfg.odometer.resolution_m
    assert np.all(diff > -1e-6) and np.all(diff < res + 1e-6)
    # the 3-D path is longer than the chainage (grades, irregularities), as it must be
    assert path[-1] > tr.chainage_m[-1] - tr.chainage_m[0]


def test_fixes_within_five_sigma_of_truth_prism(noisy):
    tr, ses, cfg = noisy.truth, noisy.session, noisy.config
    fx = ses.fixes
    idx = np.rint(fx.t_s * cfg.imu_rate_hz).astype(int) - 1
    rot = _truth_rotation(tr, idx)
    lever_n = rot.apply(np.asarray(cfg.trolley.prism_lever_arm_m))
    prism = np.column_stack([tr.E_m[idx] + lever_n[:, 1], tr.N_m[idx] + lever_n[:, 0],
                             tr.H_m[idx] - lever_n[:, 2]])
    err = fx.enh_m - prism
    assert np.all(np.abs(err) < 5 * fx.sigma_m)
    assert np.std(err) > 0.2 * cfg.fix_sigma_m     # noise really applied
    # the first fix is taken during the static alignment
    assert fx.t_s[0] < cfg.static_s


def test_stops_every_fix_spacing(noisy):
    tr, cfg = noisy.truth, noisy.config
    s = tr.chainage_m
    still = np.concatenate([[True], np.diff(s) == 0.0])
    edges = np.flatnonzero(np.diff(still.astype(int)))
    starts = np.concatenate([[0], edges[1::2] + 1])
    stop_s = s[starts]
    s0 = small_alignment().start_chainage_m
    expected = s0 + cfg.fix_spacing_m * np.arange(int(cfg.length_m // cfg.fix_spacing_m) + 1)
    expected = np.append(expected, s0 + cfg.length_m)
    np.testing.assert_allclose(stop_s, expected, atol=1e-9)
    # durations: static_s first, then stop_s
    ends = np.concatenate([edges[0::2], [s.size - 1]])
    dur = (ends - starts) / cfg.imu_rate_hz
    assert abs(dur[0] - cfg.static_s) < 0.05
    np.testing.assert_allclose(dur[1:], cfg.stop_s, atol=0.05)
    speed = np.diff(s) * cfg.imu_rate_hz
    assert 0.95 * cfg.speed_m_s < speed.max() <= cfg.speed_m_s * (1 + 1e-9)


def test_truth_is_design_plus_irregularities(noisy):
    """Projected onto the design, the truth track's offsets are the stated irregularities."""
    tr, cfg = noisy.truth, noisy.config
    prof = tr.resampled(0.5)
    proj = small_alignment().project(prof.E_m, prof.N_m, prof.H_m)
    np.testing.assert_allclose(proj.chainage_m, prof.chainage_m, atol=2e-6)
    np.testing.assert_allclose(proj.lateral_m, prof.lateral_m, atol=1e-7)
    np.testing.assert_allclose(proj.vertical_m, prof.vertical_m, atol=1e-7)
    rms = np.sqrt(np.mean(prof.lateral_m ** 2))
    assert 0.7 * cfg.irregularity_rms_m < rms < 1.3 * cfg.irregularity_rms_m
    # gauge and cant carry irregularities of the stated size around the design
    design = small_alignment().evaluate(prof.chainage_m)
    xlevel = prof.cant_m - cfg.trolley.rail_spacing_m * np.sin(design.cant_rad)
    assert 0.5e-4 < np.std(xlevel) < 2e-3
    assert 0.5e-4 < np.std(prof.gauge_m - cfg.trolley.nominal_gauge_m) < 2e-3


def test_seeded_and_reproducible():
    cfg = replace(BASE, length_m=60.0, static_s=5.0, stop_s=2.0)
    a = simulate_survey(small_alignment(), cfg).session
    b = simulate_survey(small_alignment(), cfg).session
    c = simulate_survey(small_alignment(), replace(cfg, seed=4)).session
    np.testing.assert_array_equal(a.imu_w_rad_s, b.imu_w_rad_s)
    np.testing.assert_array_equal(a.fixes.enh_m, b.fixes.enh_m)
    assert not np.array_equal(a.imu_w_rad_s, c.imu_w_rad_s)


def test_one_track_seed_is_one_track_surveyed_twice():
    """``track_seed`` fixes the irregularities alone: two seeds survey the same rails with their own
    sensor errors (a repeat run, ``trolley compare``); without it the seed draws both, as before."""
    cfg = replace(BASE, length_m=60.0, static_s=5.0, stop_s=2.0)
    a = simulate_survey(small_alignment(), replace(cfg, track_seed=11))
    b = simulate_survey(small_alignment(), replace(cfg, seed=4, track_seed=11))
    c = simulate_survey(small_alignment(), replace(cfg, seed=4))
    s = np.linspace(1001.0, 1059.0, 300)
    ta, tb, tc = (x.truth.geometry.extras(s) for x in (a, b, c))
    np.testing.assert_array_equal(ta, tb)                      # roll, gauge, lateral, vertical
    assert np.std(ta[:, 2]) > 1e-4 and np.max(np.abs(ta[:, 2] - tc[:, 2])) > 1e-4
    assert not np.array_equal(a.session.imu_w_rad_s, b.session.imu_w_rad_s)
    assert not np.array_equal(a.session.fixes.enh_m, b.session.fixes.enh_m)


def test_gyro_errors_have_datasheet_size(noisy):
    """Static gyro noise: the sample std matches ARW/sqrt(dt); mean error within bias sigma."""
    clean_w = simulate_survey(small_alignment(), replace(BASE, errors=False)).session.imu_w_rad_s
    cfg = noisy.config
    static = noisy.session.imu_t_s < cfg.static_s
    err = noisy.session.imu_w_rad_s[static] - clean_w[static]
    sigma = cfg.imu.gyro_arw_rad_sqrt_s * np.sqrt(cfg.imu_rate_hz)
    np.testing.assert_allclose(err.std(axis=0), sigma, rtol=0.1)
    # mean over the static period: turn-on bias + GM (both ~ BI), well inside 5 sigma
    assert np.all(np.abs(err.mean(axis=0)) < 5 * np.sqrt(2) * cfg.imu.gyro_bias_instability_rad_s
                  + 5 * sigma / np.sqrt(static.sum()))


def test_odometer_scale_error_scales_the_3d_path():
    """Constant scale error only: every leg's odometer/path ratio is the same 1 + dk0."""
    from trolley.sensors import IMU_PRESETS, OdometerFigures

    cfg = replace(BASE, odometer=OdometerFigures(scale_noise_per_sqrt_s=0.0, scale_error=1e-3,
                                                 resolution_m=1e-4),
                  imu=IMU_PRESETS["rlg"], seed=11)
    sim = simulate_survey(small_alignment(), cfg)
    m, ses = sim.truth.motion, sim.session
    g = sim.truth.geometry
    # odometer at the middle of each stop vs the true 3-D path length of each leg
    t_mid = 0.5 * (m.stop_start_s + m.stop_end_s)
    odo = np.interp(t_mid, ses.odo_t_s, ses.odo_distance_m)
    p = np.column_stack([sim.truth.E_m, sim.truth.N_m, sim.truth.H_m])
    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    path = np.interp(t_mid, sim.truth.t_s, chord)
    ratio = np.diff(odo) / np.diff(path)
    assert np.ptp(ratio[:3]) < 2 * 1e-4 / 60.0 + 1e-9       # one count over a 60 m leg
    dk0 = ratio[0] - 1.0
    assert 1e-6 < abs(dk0) < 5e-3
    assert g.arclength(g.end_chainage_m) == pytest.approx(chord[-1], abs=1e-6)


def test_accelerometer_bias_and_noise_sizes(noisy, clean):
    cfg = noisy.config
    static = noisy.session.imu_t_s < cfg.static_s
    err = noisy.session.imu_f_m_s2[static] - clean.session.imu_f_m_s2[static]
    sigma = cfg.imu.accel_vrw_m_s_sqrt_s * np.sqrt(cfg.imu_rate_hz)
    np.testing.assert_allclose(err.std(axis=0), sigma, rtol=0.1)
    mean = err.mean(axis=0)
    # the residual mounting (3e-3 deg) tilts gravity by < 5e-4 m/s^2 on x, y
    assert np.all(np.abs(mean) < 5 * cfg.imu.accel_bias_m_s2 + 5e-4)
    assert np.any(np.abs(mean) > 0.05 * cfg.imu.accel_bias_m_s2)


def test_a_turned_trolley_runs_backwards_in_its_own_frame():
    design = parse_landxml((Path(__file__).resolve().parents[1] / "projects/demo/alignment.xml").read_text())
    cfg = SimulationConfig(length_m=180.0, static_s=60.0, stop_s=30.0, turn_at_stops=(1,), turn_s=10.0,
                              errors=False, seed=4)
    sim = simulate_survey(design, cfg)
    m, s = sim.truth.motion, sim.session
    t0 = m.turn_start_s[0]
    assert m.stop_start_s[1] < t0 and t0 + cfg.turn_s < m.stop_end_s[1]
    # the gyros see the half turn about the trolley's z axis: pi, less the Earth rate's share
    k = (s.imu_t_s > t0) & (s.imu_t_s <= t0 + cfg.turn_s)
    assert abs(np.sum(s.imu_w_rad_s[k, 2]) / cfg.imu_rate_hz - np.pi) < 1e-3
    # afterwards the odometer counts down by the path length of the rest of the survey
    after = s.odo_t_s > m.stop_end_s[1]
    assert np.all(np.diff(s.odo_distance_m[after]) <= 0)
    travelled = float(sim.truth.geometry.arclength(m.stop_chainage_m[-1]) - sim.truth.geometry.arclength(m.stop_chainage_m[1]))
    assert abs((s.odo_distance_m[-1] - s.odo_distance_m[after][0]) + travelled) < 2e-4
    # the turned trolley's yaw is the track's plus pi; its roll is minus the track's
    late = sim.truth.t_s > m.stop_end_s[1] + 5.0
    track = sim.truth.at_chainage(sim.truth.chainage_m[late])
    assert np.allclose(np.angle(np.exp(1j * (sim.truth.yaw_rad[late] - track.yaw_rad - np.pi))), 0.0, atol=1e-9)
    assert np.allclose(sim.truth.roll_rad[late], -track.roll_rad, atol=1e-9)
    # two fixes at the turn stop, before and after; equal without a lateral lever arm
    at_stop = (s.fixes.t_s > m.stop_start_s[1]) & (s.fixes.t_s < m.stop_end_s[1])
    assert at_stop.sum() == 2
    assert s.fixes.t_s[at_stop][0] < t0 < t0 + cfg.turn_s < s.fixes.t_s[at_stop][1]


def test_a_turn_needs_a_long_enough_stop():
    with pytest.raises(ValueError, match="needs stops of at least"):
        motion_profile(0.0, 120.0, 60.0, 10.0, 12.0, 1.0, 4.0, turn_at_stops=(1,), turn_s=10.0)
    with pytest.raises(ValueError, match="static alignment"):
        motion_profile(0.0, 120.0, 60.0, 10.0, 30.0, 1.0, 4.0, turn_at_stops=(0,))


def test_progress_reports_each_chunk_and_leaves_the_draws_alone(noisy, monkeypatch):
    """The simulate command's progress bar: one report per chunk of IMU samples, fractions rising
    from 0 below 1, and the same survey as without a progress callable."""
    import trolley.truthsim as ts

    monkeypatch.setattr(ts, "_CHUNK", 4096)
    seen: list[tuple[str, float]] = []
    sim = simulate_survey(small_alignment(), BASE, progress=lambda step, f: seen.append((step, f)))
    n = noisy.session.imu_t_s.size
    assert len(seen) == -(-n // 4096)
    fractions = [f for _, f in seen]
    assert fractions[0] == 0.0 and fractions == sorted(fractions) and fractions[-1] < 1.0
    np.testing.assert_array_equal(sim.session.imu_w_rad_s, noisy.session.imu_w_rad_s)
    np.testing.assert_array_equal(sim.session.imu_f_m_s2, noisy.session.imu_f_m_s2)
    np.testing.assert_array_equal(sim.session.fixes.enh_m, noisy.session.fixes.enh_m)
