"""Dead reckoning: prefix scans against sequential products; exact straight-line and turning runs."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from trolley import earth
from trolley.deadreckoning import _block_rotvecs, dead_reckon, prefix_compose, static_alignment


@given(seed=st.integers(0, 10_000), n=st.integers(1, 70), reverse=st.booleans(), chunk=st.sampled_from([2, 3, 8, 64]))
@settings(max_examples=60, deadline=None)
def test_prefix_compose_equals_sequential_product(seed, n, reverse, chunk):
    rots = Rotation.random(n, random_state=seed)
    got = prefix_compose(rots, reverse=reverse, chunk=chunk)
    acc = rots[0]
    assert (got[0] * acc.inv()).magnitude() < 1e-12
    for k in range(1, n):
        acc = rots[k] * acc if reverse else acc * rots[k]
        assert (got[k] * acc.inv()).magnitude() < 1e-12


@given(seed=st.integers(0, 10_000))
@settings(max_examples=30, deadline=None)
def test_block_rotation_vector_is_third_order_exact(seed):
    rng = np.random.default_rng(seed)
    incr = rng.normal(0, 1e-4, (10, 3))
    exact = Rotation.identity()
    for a in incr:
        exact = exact * Rotation.from_rotvec(a)
    got = Rotation.from_rotvec(_block_rotvecs(incr, np.ones(10), 10)[0])
    total = np.abs(incr).sum()
    # the neglected terms are third order in the block's angle (random, coning-like increments)
    assert (got * exact.inv()).magnitude() < max(1e-15, 0.1 * total**3)
    # dropping the commutation term costs second order: the correction is really there
    plain = Rotation.from_rotvec(incr.sum(axis=0))
    assert (plain * exact.inv()).magnitude() > 100 * (got * exact.inv()).magnitude()


def _straight_run(psi, pitch, roll, lat=np.deg2rad(28.0), rate=200.0, T=260.0, static=100.0):
    t = np.arange(0.0, T, 1.0 / rate)
    v = np.clip((t - static) / 5.0, 0.0, 1.0)
    d = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) / rate)])
    C = Rotation.from_euler("ZYX", [psi, pitch, roll])
    vn = C.apply([1.0, 0.0, 0.0])[None, :] * v[:, None]
    w_n = earth.earth_rate_n(lat)[None, :] + earth.transport_rate_n(vn, lat, 50.0)
    w_b = C.inv().apply(w_n)
    g = earth.normal_gravity_m_s2(lat, 50.0)
    f_b = np.repeat(C.inv().apply([0.0, 0.0, -g])[None, :], t.size, axis=0)
    return t, w_b, f_b, d, C, lat


@given(psi=st.floats(-3.1, 3.1), pitch=st.floats(-0.02, 0.02), roll=st.floats(-0.1, 0.1))
@settings(max_examples=15, deadline=None)
def test_gyrocompassing_and_levelling_are_exact_on_perfect_data(psi, pitch, roll):
    t, w, f, d, C, lat = _straight_run(psi, pitch, roll, T=110.0)
    al = static_alignment(t, w, f, 100.0, lat, np.zeros(3))
    assert abs(al.roll_rad - roll) < 1e-9 and abs(al.pitch_rad - pitch) < 1e-9
    assert abs(np.angle(np.exp(1j * (al.heading_rad - psi)))) < 1e-8


def test_straight_run_with_earth_and_transport_rate_is_exact():
    t, w, f, d, C, lat = _straight_run(0.6, 0.004, 0.03)
    al = static_alignment(t, w, f, 100.0, lat, np.zeros(3))
    dr = dead_reckon(t, w, t, d, al, lat, 50.0, np.zeros(3))
    expected = C.apply([1.0, 0.0, 0.0]) * dr.distance_m[-1]
    assert np.max(np.abs(dr.position_ned_m[-1] - expected)) < 1e-6  # 1 micrometre over 155 m
    assert (dr.trolley_to_nav[-1] * C.inv()).magnitude() < 1e-8


def test_transport_rate_matters():
    # without the transport-rate compensation a northbound 155 m run would tilt by ~2.4e-5 rad
    t, w, f, d, C, lat = _straight_run(0.0, 0.0, 0.0)
    al = static_alignment(t, w, f, 100.0, lat, np.zeros(3))
    dr = dead_reckon(t, w, t, d, al, lat, 50.0, np.zeros(3))
    assert abs(dr.position_ned_m[-1, 2]) < 1e-6


def test_mounting_misalignment_is_applied():
    eps = np.array([0.001, -0.002, 0.003])
    t, w_t, f_t, d, C, lat = _straight_run(0.3, 0.0, 0.0)
    b_to_bt = Rotation.from_euler("ZYX", eps[::-1])  # C_b^bt = Rz Ry Rx
    w_b = b_to_bt.inv().apply(w_t)  # IMU-frame measurements of a misaligned IMU
    f_b = b_to_bt.inv().apply(f_t)
    al = static_alignment(t, w_b, f_b, 100.0, lat, eps)
    assert abs(al.heading_rad - 0.3) < 1e-8
    dr = dead_reckon(t, w_b, t, d, al, lat, 50.0, eps)
    expected = C.apply([1.0, 0.0, 0.0]) * dr.distance_m[-1]
    assert np.max(np.abs(dr.position_ned_m[-1] - expected)) < 1e-6


def test_stop_levels_recover_roll_and_pitch_only_from_standing_samples():
    from trolley.deadreckoning import stop_levels
    t, w, f, d, C, lat = _straight_run(0.2, 0.003, 0.04)
    # a bump while moving must not leak into the stop's level: add a lateral kick during motion
    f = f.copy()
    f[t > 101.0, 1] += 0.5
    roll, pitch = stop_levels(t, f, t, d, np.array([50.0, 150.0]), np.zeros(3))
    assert abs(roll[0] - 0.04) < 1e-9 and abs(pitch[0] - 0.003) < 1e-9
    assert np.isnan(roll[1])  # no standing sample around t=150 s: not guessed


def test_corrected_dead_reckoning_rotates_and_scales_exactly():
    from trolley.engine import corrected_dead_reckoning
    t, w, f, d, C, lat = _straight_run(0.6, 0.0, 0.0)
    al = static_alignment(t, w, f, 100.0, lat, np.zeros(3))
    dr = dead_reckon(t, w, t, d, al, lat, 50.0, np.zeros(3))
    states = np.zeros((dr.t_s.size, 8))
    states[:, 3] = 0.01   # heading error phi_D: the estimate is 0.01 rad short of the truth
    states[:, 2] = 1e-3   # odometer reads 0.1 % long
    fixed = corrected_dead_reckoning(dr, states)
    expected = Rotation.from_rotvec([0.0, 0.0, 0.01]).apply(dr.position_ned_m[-1]) / 1.001
    assert np.max(np.abs(fixed.position_ned_m[-1] - expected)) < 1e-9


def test_block_rotation_vectors_do_not_depend_on_the_chunking():
    # 1003 increments: 101 blocks of 10, the last one short; chunks of 7 blocks vs one chunk
    rng = np.random.default_rng(3)
    rate, dt = rng.normal(0, 1e-2, (1003, 3)), rng.uniform(0.004, 0.006, 1003)
    one = _block_rotvecs(rate, dt, 10, chunk_blocks=1000)
    np.testing.assert_array_equal(_block_rotvecs(np.asfortranarray(rate), dt, 10, chunk_blocks=7), one)
    # the short last block is the rotation of its 3 increments alone
    last = Rotation.identity()
    for a in rate[1000:] * dt[1000:, None]:
        last = last * Rotation.from_rotvec(a)
    assert (Rotation.from_rotvec(one[-1]) * last.inv()).magnitude() < 1e-12
    assert one.shape == (101, 3)


def test_handling_blocks_finds_lifts_and_turns_of_a_standing_trolley():
    from trolley.deadreckoning import DeadReckoning, handling_blocks
    # 60 blocks: moving 0-9, standing 10-19 (lifted: tilted 0.3 rad at 14..16), moving 20-29,
    # standing 30-39 (turned 180 deg from 33 on), moving 40-49, standing 50-59 (turned 360 deg)
    n = 60
    d = np.concatenate([np.arange(10.0), np.full(10, 10.0), 10 + np.arange(1.0, 11.0), np.full(10, 20.0),
                        20 - np.arange(1.0, 11.0), np.full(10, 10.0)])
    yaw = np.full(n, 0.2)
    roll = np.zeros(n)
    roll[14:17] = 0.3
    yaw[33:] += np.pi
    yaw[52:] += np.linspace(0.0, 2 * np.pi, 8)
    # on grades of 8, -5 and 3 mrad at the three stops (a turned trolley faces down the grade)
    pitch = np.full(n, 0.008)
    pitch[29:] = -0.005  # from the block at which it arrives
    pitch[33:] = 0.005
    pitch[49:] = 0.003
    R = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))
    dr = DeadReckoning(t_s=np.arange(n, dtype=float), distance_m=d, trolley_to_nav=R,
                       position_ned_m=np.zeros((n, 3)))
    blocks, turned, heading, grade = handling_blocks(dr)
    np.testing.assert_array_equal(blocks, [14, 33, 53])
    np.testing.assert_array_equal(turned, [False, True, False])
    np.testing.assert_allclose(np.angle(np.exp(1j * (heading - [0.2, 0.2, 0.2 + np.pi]))), 0.0, atol=1e-12)
    # the pitch where each standstill began, not the tilted or turned one
    np.testing.assert_allclose(grade, [0.008, -0.005, 0.003], atol=1e-12)


def test_stop_levels_equal_a_direct_per_stop_mean():
    # stops at 20-40 s and 60-80 s; two fix times 4 s apart in the first stop (overlapping windows),
    # a crew lift (0.3 rad/s for 1 s) at 70 s in the second, a misaligned IMU, noisy accelerometers
    from trolley.deadreckoning import mounting_rotation, stop_levels
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 100.0, 0.01)
    v = np.where((t > 20) & (t < 40) | (t > 60) & (t < 80), 0.0, 1.0)
    d = np.concatenate([[0.0], np.cumsum(v[1:] * 0.01)])
    f = rng.normal(0.0, 0.01, (t.size, 3)) + [0.05, -0.3, -9.8]
    w = rng.normal(0.0, 1e-5, (t.size, 3))
    lift = (t >= 70.0) & (t < 71.0)
    w[lift, 0] += 0.3
    f[t >= 70.0] += [0.0, 2.9, 0.4]  # tilted after the lift
    mis = np.array([0.01, -0.02, 0.03])
    stops = np.array([28.0, 32.0, 65.0])
    roll, pitch = stop_levels(t, np.asfortranarray(f), t, d, stops, mis, w_rad_s=np.asfortranarray(w))
    R = mounting_rotation(mis)
    for k, ts in enumerate(stops):
        lo = np.searchsorted(t, ts - 10.0)
        win = (np.arange(t.size) >= lo) & (np.arange(t.size) < np.searchsorted(t, ts + 10.0))
        # standing: odometer equal 0.05 s either side; attitude within 2 mrad of the stop time's
        still = np.array([np.interp(x - 0.05, t, d) == np.interp(x, t, d) == np.interp(x + 0.05, t, d) for x in t])
        rot = np.cumsum(w * np.diff(t, prepend=t[0])[:, None], axis=0)
        near = np.linalg.norm(rot - rot[np.searchsorted(t, ts)], axis=1) < 0.002
        use = win & still & near
        m = R.apply(f[use]).mean(axis=0)
        assert roll[k] == pytest.approx(np.arctan2(-m[1], -m[2]), abs=1e-12)
        assert pitch[k] == pytest.approx(np.arctan2(m[0], np.hypot(m[1], m[2])), abs=1e-12)
    # the tilt after the lift (70 s, inside the window 55-75 s) is not in the level: the roll is
    # the IMU's atan2(0.3, 9.8) less the 0.01 rad mounting roll, not the lifted -0.27 rad
    assert roll[2] == pytest.approx(np.arctan2(0.3, 9.8) - 0.01, abs=2e-3)


def test_roll_levelled_at_a_stop_taken_during_the_static_alignment_holds_from_the_start():
    # The first fix is taken while the trolley stands for the static alignment, before the dead
    # reckoning starts; its level holds at the start. The gyro roll drifts from the start (t = 120
    # s) at 1e-5 rad/s; the stops at 60 s (in the alignment) and 259 s level it. Pinned at 60 s,
    # the linear removal took 60/199 of the drift at the start: 3.6e-4 rad, 0.5 mm of cant.
    from trolley.deadreckoning import DeadReckoning, levelled_stop_times, with_roll_levelled
    t = np.arange(120.0, 400.0, 0.5)
    true_roll = 0.02
    roll_dr = true_roll + 1e-5 * (t - 120.0)
    att = Rotation.from_euler("ZYX", np.column_stack([np.full_like(t, 0.3), np.zeros_like(t), roll_dr]))
    dr = DeadReckoning(t_s=t, distance_m=t - 120.0, trolley_to_nav=att, position_ned_m=np.zeros((t.size, 3)))
    stops = np.array([60.0, 259.0])
    levels = np.array([true_roll, true_roll])
    out = with_roll_levelled(dr, stops, levels)
    err = out.euler_rad()[:, 0] - true_roll
    # linear drift between two levels is removed exactly; after the last stop it is held
    inside = t <= 259.0
    assert np.max(np.abs(err[inside])) < 1e-12
    assert np.allclose(err[~inside], 1e-5 * (t[~inside] - 259.0), atol=1e-12)
    assert np.array_equal(levelled_stop_times(dr, stops, levels), [120.0, 259.0])
    # two levels at one pinned time (two fixes in the alignment) are averaged, a NaN level skipped
    out2 = with_roll_levelled(dr, np.array([30.0, 60.0, 150.0, 259.0]),
                              np.array([true_roll - 1e-4, true_roll + 1e-4, np.nan, true_roll]))
    assert np.max(np.abs(out2.euler_rad()[inside, 0] - true_roll)) < 1e-12
