"""IMU driver against its twin through a real pty: corruption, drops, garbage, unplug, replay."""
from __future__ import annotations

import time

import numpy as np
import pytest

from drivers import novatel as nv
from drivers.replay import replay_imu
from drivers.serialport import SerialLink
from drivers.stats import Stats
from drivers.twins.base import Faults
from drivers.twins.imu import ImuTwin
from polling import wait_until

L = nv.FRAME_LEN


def _arrays(n, rate, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    w = rng.normal(0.0, 0.2, (n, 3))
    f = rng.normal(0.0, 1.0, (n, 3)) + [0.0, 0.0, -9.80665]
    return t, w, f


def _run(twin, rate, raw_log=None, timeout_s=60.0):
    stats = Stats()
    link = SerialLink(twin.port, nv.RawImuParser(stats, rate), "imu", raw_log=raw_log)
    link.open()  # pyserial side first, then the twin (deps.md section 6)
    link.start()
    twin.start()
    wait_until(lambda: twin.frames_sent >= twin.n_frames and link.snapshot().bytes_in >= twin.bytes_sent, timeout_s)
    link.stop()
    twin.stop()
    return link, nv.ImuFrames.concat(link.drain()), stats


def _expected_loss(inj, n):
    """Frames hit by an injected fault, and those hit only after their 3 sync bytes."""
    hit = set((np.array(inj.corrupted + inj.dropped, int) // L).tolist())
    hit |= {off // L for off, _ in inj.garbage if off % L}
    sync_hit = {o // L for o in inj.corrupted + inj.dropped if o % L < 3}
    return {h for h in hit if h < n}, sync_hit


@pytest.mark.parametrize("rate", [200.0, 1000.0])
def test_60s_stream_with_1e4_corruption_loses_only_crc_failures(rate):
    n = int(60 * rate)
    t, w, f = _arrays(n, rate)
    twin = ImuTwin(t, w, f, imu_type=26, rate_hz=rate, realtime=False, chunk_frames=64,
                   faults=Faults(corrupt_rate=1e-4, seed=7))
    t0 = time.perf_counter()
    link, fr, st = _run(twin, rate)
    elapsed = time.perf_counter() - t0
    hit, sync_hit = _expected_loss(twin.injector, n)
    good = np.array(sorted(set(range(n)) - hit))
    assert len(twin.injector.corrupted) > 0.5e-4 * n * L
    # frames lost exactly where a fault was injected, every other frame recovered intact
    assert len(fr) == len(good) == st.frames_ok
    assert np.array_equal(fr.gyro_counts, twin.gyro_counts[good])
    assert np.array_equal(fr.accel_counts, twin.accel_counts[good])
    assert np.array_equal(fr.sow_s, twin.sow[good])
    # each lost frame is a CRC failure, except those whose sync bytes were destroyed
    assert st.bad_checksum == len(hit - sync_hit)
    assert st.extra["frames_missing"] == len(hit)
    assert st.bytes_in == n * L and st.balanced() and st.bytes_ok == len(good) * L
    print(f"\n{rate:.0f} Hz x 60 s: {n} frames, {len(twin.injector.corrupted)} bytes corrupted, "
          f"{len(hit)} frames hit, {st.frames_ok} accepted, bad CRC {st.bad_checksum}, "
          f"sync destroyed {len(hit - (hit - sync_hit))}, {elapsed:.2f} s wall")


def test_drops_garbage_corruption_all_good_frames_recovered_and_bytes_accounted():
    n = 6000
    t, w, f = _arrays(n, 200.0, 1)
    twin = ImuTwin(t, w, f, realtime=False, chunk_frames=8,
                   faults=Faults(corrupt_rate=2e-4, drop_rate=2e-4, garbage_rate=0.2, garbage_len=(1, 200), seed=3))
    link, fr, st = _run(twin, 200.0)
    hit, _ = _expected_loss(twin.injector, n)
    good = np.array(sorted(set(range(n)) - hit))
    assert len(twin.injector.garbage) > 50 and len(twin.injector.dropped) > 20
    assert np.array_equal(fr.gyro_counts, twin.gyro_counts[good])
    assert np.array_equal(fr.sow_s, twin.sow[good])
    assert st.bytes_in == twin.bytes_sent and st.balanced()
    assert st.resyncs >= len(twin.injector.garbage) // 2


def test_unplug_and_replug_keeps_received_frames_and_replays_identically(tmp_path):
    rate = 500.0
    n = 600  # 1.2 s of real time
    t, w, f = _arrays(n, rate, 2)
    twin = ImuTwin(t, w, f, rate_hz=rate, realtime=True, link_path=tmp_path / "imu-by-id")
    stats = Stats()
    link = SerialLink(twin.port, nv.RawImuParser(stats, rate), "imu", raw_log=tmp_path / "imu.rawlog")
    link.open()
    link.start()
    twin.start()
    time.sleep(0.35)
    before = nv.ImuFrames.concat(link.drain())
    twin.disappear(0.3)
    wait_until(lambda: twin.frames_sent >= n, 20.0, 0.02)
    time.sleep(0.2)
    link.stop()
    twin.stop()
    after = nv.ImuFrames.concat(link.drain())
    live = nv.ImuFrames.concat([before, after])
    assert stats.reconnects == 1
    assert len(before) > 30 and len(after) > 30
    # frames are in order, each exactly one that was sent; the gap is the unplugged time
    idx = np.searchsorted(twin.sow, live.sow_s)
    assert np.array_equal(twin.sow[idx], live.sow_s) and np.all(np.diff(idx) > 0)
    assert np.array_equal(live.gyro_counts, twin.gyro_counts[idx])
    assert idx[0] == 0 and stats.extra["time_gaps"] >= 1
    # the raw log replays byte for byte into identical records
    rep, rstats = replay_imu(tmp_path / "imu.rawlog", rate)
    for name in ("t_host_s", "sow_s", "gyro_counts", "accel_counts", "imu_info", "status"):
        assert np.array_equal(getattr(rep, name), getattr(live, name))
    assert (rstats.frames_ok, rstats.bytes_in, rstats.bad_checksum) == (stats.frames_ok, stats.bytes_in, stats.bad_checksum)


def test_axis_map_and_si_through_pty():
    n = 400
    t, w, f = _arrays(n, 200.0, 4)
    twin = ImuTwin(t, w, f, imu_type=58, rate_hz=200.0, axes="y,-x,-z", realtime=False)
    _, fr, st = _run(twin, 200.0)
    wr, fr_si = fr.to_si(nv.imu_scale(58, 200.0), nv.axis_matrix("y,-x,-z"))
    sc = nv.imu_scale(58, 200.0)
    assert np.max(np.abs(wr - w)) <= 0.5 * sc.gyro * 200.0 * 1.0001
    assert np.max(np.abs(fr_si - f)) <= 0.5 * sc.accel * 200.0 * 1.0001


def test_silence_counts_one_timeout_then_data_flows():
    t, w, f = _arrays(100, 200.0, 6)
    twin = ImuTwin(t, w, f, realtime=False)
    stats = Stats()
    link = SerialLink(twin.port, nv.RawImuParser(stats, 200.0), "imu", idle_timeout_s=0.15)
    link.open()
    link.start()
    wait_until(lambda: link.snapshot().timeouts > 0, 10.0, 0.02)
    time.sleep(0.3)  # still silent: still one timeout
    silent = link.snapshot()
    twin.start()
    wait_until(lambda: link.snapshot().frames_ok >= 100, 10.0, 0.02)
    link.stop()
    twin.stop()
    assert silent.timeouts == 1 and silent.bytes_in == 0 and stats.frames_ok == 100
