"""GeoCOM client against the total-station twin through a real pty, with every fault."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from drivers import geocom as gc
from drivers.totalstation import RetryPolicy, TotalStation
from drivers.twins.base import Faults
from drivers.twins.totalstation import TotalStationTwin

STATION = (1000.0, 2000.0, 50.0, 1.55)
TARGET = (1012.0, 2030.0, 50.8)


def _pair(tmp_path=None, faults=None, use_crc=False, timeout_s=2.0, retry=RetryPolicy(attempts=5), **kw):
    twin = TotalStationTwin(STATION, TARGET, faults=faults,
                            link_path=(tmp_path / "ts-by-id") if tmp_path else None, **kw)
    ts = TotalStation(twin.port, baudrate=9600, use_crc=use_crc, timeout_s=timeout_s,
                      long_timeout_s=timeout_s, retry=retry,
                      raw_log=(tmp_path / "ts.rawlog") if tmp_path else None)
    ts.link.open()
    twin.start()
    ts.connect()
    return twin, ts


def _polar(station, target):
    e0, n0, h0, hi = station
    de, dn, dh = target[0] - e0, target[1] - n0, target[2] - h0 - hi
    hd = math.hypot(de, dn)
    return math.atan2(de, dn) % (2 * math.pi), math.atan2(hd, dh), math.sqrt(hd * hd + dh * dh)


def test_probe_sequence_geometry_and_station():
    twin, ts = _pair(use_crc=True)
    try:
        assert ts.sw_version() == (1, 50, 0)
        ts.fine_adjust()
        m = ts.measure()
        hz, v, sd = _polar(STATION, TARGET)
        assert (m.hz_rad, m.v_rad, m.slope_m) == pytest.approx((hz, v, sd), abs=1e-12)
        assert (m.E_m, m.N_m, m.H_m) == pytest.approx(TARGET, abs=1e-9)
        # free station on CPIII: new station and orientation; coordinates follow the station
        ts.set_station(1001.0, 2001.0, 49.0, 1.60)
        assert ts.station() == pytest.approx((1001.0, 2001.0, 49.0, 1.60))
        ts.fine_adjust()
        ts.set_orientation(1.0)  # the current direction now reads Hz = 1.0 rad
        ts.do_measure()
        hz2, v2, sd2, _ = ts.simple_mea()
        assert hz2 == pytest.approx(1.0, abs=1e-12)
        e, n, h, _ = ts.coordinate()
        e0, n0, h0, hi = 1001.0, 2001.0, 49.0, 1.60
        assert e == pytest.approx(e0 + sd2 * math.sin(v2) * math.sin(1.0), abs=1e-9)
        assert n == pytest.approx(n0 + sd2 * math.sin(v2) * math.cos(1.0), abs=1e-9)
        assert h == pytest.approx(h0 + hi + sd2 * math.cos(v2), abs=1e-9)
        # BAP_MeasDistanceAngle and TMC_GetAngle agree with TMC_GetSimpleMea
        hz3, v3, sd3 = ts.meas_distance_angle()
        assert (hz3, v3, sd3) == pytest.approx((hz2, v2, sd2), abs=1e-12)
        assert ts.angle() == pytest.approx((hz2, v2), abs=1e-12)
        # reflector height: the measured point is that far below the prism
        ts.set_reflector_height(0.25)
        ts.do_measure()
        assert ts.coordinate()[2] == pytest.approx(h - 0.25, abs=1e-9)
        # turning away and back with ATR positioning finds the prism again
        ts.make_positioning(0.0, 1.5, atr=True)
        assert ts.angle()[0] == pytest.approx(1.0, abs=1e-12)
        assert ts.stats.balanced() and ts.stats.bad_checksum == 0
        assert all(r.crc_present and r.crc_ok for r in twin.requests)
    finally:
        ts.close()
        twin.stop()


def test_retryable_codes_are_retried_then_succeed_and_others_raise_at_once():
    twin, ts = _pair(retry=RetryPolicy(attempts=5, base_delay_s=0.01))
    try:
        twin.inject_rc(8710, gc.AUT_FINEADJUST, times=2)  # no target, twice
        twin.inject_rc(8725, gc.TMC_DOMEASURE)  # ATR not locked
        twin.inject_rc(13, gc.TMC_GETSIMPLEMEA)  # busy
        ts.fine_adjust()
        m = ts.measure()
        assert ts.stats.extra["retries"] == 4
        assert (m.E_m, m.N_m, m.H_m) == pytest.approx(TARGET, abs=1e-9)
        twin.inject_rc(2, gc.TMC_GETSIMPLEMEA)  # invalid parameter: not transient
        n_req = len(twin.requests)
        with pytest.raises(gc.GeoComError) as e:
            ts.simple_mea()
        assert e.value.code == 2 and e.value.name == "GRC_IVPARAM" and len(twin.requests) == n_req + 1
        twin.inject_rc(8710, gc.AUT_FINEADJUST, times=10)
        with pytest.raises(gc.GeoComNoTarget) as e:
            ts.fine_adjust()
        assert e.value.code == 8710 and "No target" in str(e.value)
        with pytest.raises(gc.GeoComError) as e:
            ts.call(4242)
        assert e.value.code == 3081  # unknown RPC on this firmware
    finally:
        ts.close()
        twin.stop()


def test_missing_and_late_replies_time_out_retry_and_stale_reply_is_ignored():
    twin, ts = _pair(timeout_s=0.4, retry=RetryPolicy(attempts=5, base_delay_s=0.01))
    try:
        twin.drop_replies(2)
        ts.fine_adjust()
        assert ts.stats.timeouts >= 2  # more only if the loaded machine is slower than 0.4 s
        twin.delay_replies(1, 0.8)
        ts.do_measure()  # its reply comes after the timeout; the retry is answered in time
        hz, v, sd, _ = ts.simple_mea()
        time.sleep(0.5)  # the late reply of the first DoMeasure arrives now
        e, n, h, _ = ts.coordinate()
        assert (e, n, h) == pytest.approx(TARGET, abs=1e-9)
        assert ts.stats.timeouts >= 3 and ts.stats.extra["stale_replies"] >= 1
    finally:
        ts.close()
        twin.stop()


def test_byte_faults_with_crc_never_accept_a_corrupt_reply():
    faults = Faults(corrupt_rate=2e-3, drop_rate=1e-3, garbage_rate=0.05, garbage_len=(1, 30), seed=11)
    twin, ts = _pair(faults=faults, use_crc=True, timeout_s=0.5,
                     retry=RetryPolicy(attempts=8, base_delay_s=0.01, max_delay_s=0.05))
    try:
        ts.fine_adjust()
        ts.do_measure()
        expect = _polar(STATION, TARGET)
        ok = failed = 0
        for _ in range(100):
            try:
                r = ts.simple_mea()
            except gc.GeoComError:
                failed += 1
                continue
            ok += 1
            assert r[:3] == pytest.approx(expect, abs=1e-12)  # never a corrupt value
        st = ts.link.snapshot()
        assert ok >= 95 and len(twin.injector.corrupted) > 5
        assert st.bad_checksum + st.bad_format + st.timeouts > 0 and st.balanced()
    finally:
        ts.close()
        twin.stop()


def test_port_disappears_and_comes_back(tmp_path):
    twin, ts = _pair(tmp_path, retry=RetryPolicy(attempts=10, base_delay_s=0.05, max_delay_s=0.5))
    try:
        ts.fine_adjust()
        first = ts.measure()
        import threading

        th = threading.Thread(target=twin.disappear, args=(0.4,))
        th.start()
        time.sleep(0.1)
        second = ts.measure()  # retried until the port is back
        th.join()
        assert ts.link.snapshot().reconnects == 1
        assert (second.E_m, second.N_m) == pytest.approx((first.E_m, first.N_m), abs=1e-9)
    finally:
        ts.close()
        twin.stop()
    from drivers.replay import replay
    from drivers.totalstation import GeoComReplyParser

    recs, st = replay(tmp_path / "ts.rawlog", GeoComReplyParser)
    replies = [r for r in recs if hasattr(r, "raw")]
    assert len(replies) == st.frames_ok == ts.stats.frames_ok and st.bytes_in == ts.stats.bytes_in
    assert all(r.raw.startswith("%R1P,0,") for r in replies)


def test_noise_statistics():
    twin, ts = _pair(noise_angle_rad=1e-5, noise_dist_m=1e-3, seed=3)
    try:
        ts.fine_adjust()
        sd = []
        for _ in range(60):
            ts.do_measure()
            sd.append(ts.simple_mea()[2])
        sd = np.array(sd)
        true = _polar(STATION, TARGET)[2]
        assert abs(sd.mean() - true) < 4 * 1e-3 / np.sqrt(60)
        assert 0.6e-3 < sd.std(ddof=1) < 1.5e-3
    finally:
        ts.close()
        twin.stop()


def test_slow_atr_and_edm_calls_use_the_long_timeout():
    twin = TotalStationTwin(STATION, TARGET, atr_time_s=0.4, edm_time_s=0.3)
    ts = TotalStation(twin.port, timeout_s=0.2, long_timeout_s=5.0, retry=RetryPolicy(attempts=3))
    ts.link.open()
    twin.start()
    try:
        ts.connect()
        t0 = time.monotonic()
        ts.fine_adjust()
        m = ts.measure()
        assert time.monotonic() - t0 >= 0.4 + 2 * 0.3
        assert (m.E_m, m.N_m, m.H_m) == pytest.approx(TARGET, abs=1e-9)
        # a short timeout on the three slow calls would have timed out at least three times;
        # one spurious timeout of a quick call is allowed on a loaded machine
        assert ts.stats.timeouts <= 1
    finally:
        ts.close()
        twin.stop()


def test_free_station_on_cpiii_then_trolley_prism_coordinates():
    """Free station: measure CPIII prisms, resect on the host (trolley.resection), set station and
    orientation, then the trolley prism's TMC_GetCoordinate equals its true position."""
    from trolley.resection import PolarModel, PolarObservations, ResectionConfig, resect

    axis = np.array([1000.0, 2000.0, 51.55])  # where the instrument really stands (axis point)
    twin = TotalStationTwin((*axis[:2], 50.0, 1.55), None, noise_angle_rad=2e-6, noise_dist_m=3e-4, seed=2)
    twin.station = (0.0, 0.0, 0.0, 0.0)  # the crew does not know the station yet
    twin.orientation = 0.7  # nor the circle's orientation
    ts = TotalStation(twin.port, timeout_s=2.0, long_timeout_s=2.0)
    ts.link.open()
    twin.start()
    rng = np.random.default_rng(1)
    az = np.radians([20, 95, 170, 200, 260, 340])
    dist = rng.uniform(20.0, 60.0, az.size)
    cpiii = np.column_stack([axis[0] + dist * np.sin(az), axis[1] + dist * np.cos(az),
                             50.4 + rng.uniform(-0.3, 0.3, az.size)])
    try:
        ts.connect()
        obs = []
        for p in cpiii:
            twin.set_target(p)
            ts.fine_adjust()
            obs.append(ts.meas_distance_angle())
        obs = np.array(obs)
        res = resect([f"CP{k}" for k in range(len(cpiii))], cpiii, PolarObservations(*obs.T),
                     ResectionConfig(model=PolarModel(curvature_refraction=False)))
        assert res.station_enh_m == pytest.approx(axis, abs=2e-3)
        assert res.orientation_rad == pytest.approx(0.7, abs=2e-5)
        e, n, h_axis = res.station_enh_m
        ts.set_station(e, n, h_axis - 1.55, 1.55)
        hz_now = ts.angle()[0]  # still pointing at the last CPIII prism
        ts.set_orientation((hz_now + res.orientation_rad) % (2 * np.pi))
        prism = np.array([1015.0, 2025.0, 51.2])  # the trolley prism
        twin.set_target(prism)
        ts.fine_adjust()
        m = ts.measure()
        assert np.array([m.E_m, m.N_m, m.H_m]) == pytest.approx(prism, abs=4e-3)
    finally:
        ts.close()
        twin.stop()


def test_random_late_and_missing_replies_every_call_accounted_for():
    faults = Faults(delay_rate=0.2, delay_s=0.8, missing_rate=0.15, seed=21)
    twin, ts = _pair(timeout_s=0.5, retry=RetryPolicy(attempts=3, base_delay_s=0.01, max_delay_s=0.02))
    twin.faults = twin.injector.f = faults  # connect() above ran fault-free
    k0 = len(twin.requests)
    expect = _polar(STATION, TARGET)
    calls = ok = timed_out = 0
    try:
        ts.fine_adjust()
        ts.do_measure()
        base = len(twin.requests)
        retries0, timeouts0 = ts.stats.extra["retries"], ts.stats.timeouts
        for _ in range(30):
            calls += 1
            try:
                r = ts.simple_mea()
            except gc.GeoComTimeout as e:  # every attempt went unanswered in time: typed, code 3077
                assert e.code == 3077
                timed_out += 1
                continue
            ok += 1
            assert r[:3] == pytest.approx(expect, abs=1e-12)
        retries = ts.stats.extra["retries"] - retries0
        timeouts = ts.stats.timeouts - timeouts0
        twin.faults.delay_rate = twin.faults.missing_rate = 0.0
        time.sleep(1.0)  # the last late reply arrives
        ts.null_proc()  # drains it (counted stale)
    finally:
        ts.close()
        twin.stop()
    assert ok + timed_out == calls and ok >= 25
    # every request of the loop reached the twin: one per attempt
    assert len(twin.requests) - base - 1 == calls + retries
    faulted = [k for k in twin.missing + twin.delayed if k >= base]
    # each missing or late reply costs exactly one timeout; every late one arrives as stale
    assert timeouts == len(faulted) == retries + timed_out and len(faulted) > 5
    assert ts.stats.extra["stale_replies"] == len([k for k in twin.delayed if k >= k0])
    # every reply sent was received and parsed
    assert ts.stats.frames_ok == len(twin.requests) - len(twin.missing) and ts.stats.balanced()


def test_without_crc_a_corrupted_digit_can_pass():
    # the same reply with one digit changed: only the CRC field tells them apart
    good = gc.encode_reply(0, (1.2345678, 1.5707963, 31.622), 5).decode().strip()
    bad = good.replace("31.622", "31.722")
    assert gc.decode_reply(bad).params[2] == 31.722  # accepted, wrong by 0.1 m
    good_crc = gc.encode_reply(0, (1.2345678, 1.5707963, 31.622), 5, with_crc=True).decode().strip()
    with pytest.raises(gc.GeoComChecksumError):
        gc.decode_reply(good_crc.replace("31.622", "31.722"))
    # through the pty: byte faults without CRC; every wrong accepted value needs a corrupted
    # byte that stayed a valid character of a number (digit->digit), which nothing can catch
    faults = Faults(corrupt_rate=2e-3, seed=4)
    twin, ts = _pair(timeout_s=0.5, retry=RetryPolicy(attempts=8, base_delay_s=0.01, max_delay_s=0.05))
    twin.faults = twin.injector.f = faults
    try:
        ts.fine_adjust()
        ts.do_measure()
        expect = _polar(STATION, TARGET)
        wrong = ok = 0
        for _ in range(150):
            try:
                r = ts.simple_mea()
            except gc.GeoComError:
                continue
            ok += 1
            wrong += r[:3] != pytest.approx(expect, abs=1e-12)
    finally:
        ts.close()
        twin.stop()
    inj = twin.injector
    digits = set(b"0123456789")
    digit_swaps = sum(1 for a, b in zip(inj.corrupted_from, inj.corrupted_to) if a in digits and b in digits)
    assert ok >= 140 and len(inj.corrupted) > 10 and wrong <= digit_swaps
    print(f"\nGeoCOM without CRC: {ok} replies accepted, {len(inj.corrupted)} bytes corrupted, "
          f"{digit_swaps} digit->digit, {wrong} wrong values accepted")


def test_replies_without_transaction_id_and_coord_time_kept():
    twin, ts = _pair(echo_trid=False)
    try:
        ts.fine_adjust()
        before = int(time.monotonic() * 1000)
        m = ts.measure()
        after = int(time.monotonic() * 1000)
    finally:
        ts.close()
        twin.stop()
    assert (m.E_m, m.N_m, m.H_m) == pytest.approx(TARGET, abs=1e-9)
    assert all(r.crc_present is False for r in twin.requests)
    # the twin stamps CoordTime with its ms clock (the host's monotonic clock, mod 2^31)
    assert m.coord_time_ms is not None and (m.coord_time_ms - before) % 2**31 <= after - before


def test_probe_detects_crc_support():
    twin, ts = _pair()
    try:
        assert ts.detect_crc() is True and ts.use_crc
        ts.fine_adjust()
        m = ts.measure()
    finally:
        ts.close()
        twin.stop()
    assert (m.E_m, m.N_m, m.H_m) == pytest.approx(TARGET, abs=1e-9)
    assert all(r.crc_present and r.crc_ok for r in twin.requests[-4:])
