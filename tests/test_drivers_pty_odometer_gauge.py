"""Odometer (encoder counter) and gauge-sensor drivers against their twins through a real pty."""
from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from drivers import encoder, gauge
from drivers.lineparser import ChecksumError
from drivers.replay import replay_encoder, replay_gauge
from drivers.serialport import SerialLink
from drivers.stats import Stats
from drivers.twins.base import Faults
from drivers.twins.gauge import GaugeTwin
from drivers.twins.odometer import OdometerTwin
from polling import wait_until


# ------------------------------------------------------------------ encoder maths
@given(st.sampled_from([8, 16, 24, 32]), st.integers(0, 2**40), st.lists(st.integers(-100, 100), min_size=1, max_size=50))
@settings(max_examples=40, deadline=None)
def test_unwrap_counts_survives_rollover(bits, start, steps):
    true = start + np.concatenate([[0], np.cumsum(steps)])
    raw = true % 2**bits
    assert np.array_equal(encoder.unwrap_counts(raw, bits), true - true[0])


def test_distance_hand_computed():
    cfg = encoder.OdometerConfig(ppr=250, decode=4, wheel_diameter_m=0.2, scale=1.001, bits=16)
    # 1000 counts per revolution (X4), circumference 0.2 pi
    assert cfg.metres_per_count == pytest.approx(1.001 * np.pi * 0.2 / 1000)
    assert encoder.distance_m([65000, 65535, 464], cfg)[-1] == pytest.approx(1000 * cfg.metres_per_count)
    assert encoder.format_read_reply(4095, 70000, 16) == b"*0R004095,04464\r"
    with pytest.raises(ValueError):
        encoder.OdometerConfig(decode=3)


def _odo_link(twin, cfg, raw=None):
    stats = Stats()
    link = SerialLink(twin.port, encoder.EncoderParser(stats, cfg), "odometer", raw_log=raw)
    link.open()
    link.start()
    twin.start()
    return link, stats

def _poll_until(twin, link, cfg, done, timeout_s=20.0, settle_s=0.1, **poller_kw):
    """Poll the twin through the driver until ``done()`` or the timeout; stop everything and
    return the decoded records (``settle_s`` lets the last replies arrive)."""
    poller = encoder.OdometerPoller(link, cfg, **poller_kw).start()
    wait_until(done, timeout_s)
    poller.stop()
    time.sleep(settle_s)
    link.stop()
    twin.stop()
    return link.drain()



def test_odometer_polled_through_pty_with_rollover_and_replay(tmp_path):
    cfg = encoder.OdometerConfig(ppr=1024, decode=4, wheel_diameter_m=0.1, bits=16, rate_hz=300.0)
    n = 150
    t = np.arange(n) / cfg.rate_hz
    dist = 1.5 * t  # 1.5 m/s: ~19600 counts/s, the 16-bit counter wraps
    twin = OdometerTwin(t, dist, cfg, offset_counts=2**16 - 300, mode="index")
    link, stats = _odo_link(twin, cfg, tmp_path / "odo.rawlog")
    recs = _poll_until(twin, link, cfg, lambda: twin.polls >= n + 5, reply_timeout_s=2.0)  # no faults here
    counts = np.array([r.count1 for r in recs])
    skip = cfg.confirm - 1  # withheld until that many readings agree (the gate's first anchor)
    assert stats.extra["unconfirmed"] == skip
    assert len(recs) >= n - skip and np.array_equal(counts, twin.sent_counts[skip: skip + len(recs)])
    d = encoder.distance_m(counts, cfg)
    assert d[n - 1 - skip] == pytest.approx(dist[n - 1] - dist[skip], abs=cfg.metres_per_count)
    assert np.all(np.diff(d) >= 0) and stats.balanced() and stats.timeouts == 0
    rep, rst = replay_encoder(tmp_path / "odo.rawlog", cfg)
    assert rep == recs and rst.frames_ok == stats.frames_ok


def test_odometer_faults_only_undetectable_digit_swaps_can_pass():
    cfg = encoder.OdometerConfig(ppr=1024, decode=4, wheel_diameter_m=0.1, bits=32, rate_hz=400.0, max_speed_m_s=5.0)
    n = 400
    t = np.arange(n) / cfg.rate_hz
    twin = OdometerTwin(t, 1.0 * t, cfg, offset_counts=2**32 - 1000, mode="index",
                        faults=Faults(corrupt_rate=3e-3, drop_rate=1e-3, garbage_rate=0.05, missing_rate=0.02, seed=5))
    link, stats = _odo_link(twin, cfg)
    recs = _poll_until(twin, link, cfg, lambda: twin.polls >= n)
    sent = set(twin.sent_counts)
    wrong = [r for r in recs if r.count1 not in sent]
    inj = twin.injector
    digit = set(b"0123456789")
    digit_swaps = sum(1 for a, b in zip(inj.corrupted_from, inj.corrupted_to) if a in digit and b in digit)
    assert len(recs) > 0.8 * n and len(inj.corrupted) > 20
    assert len(wrong) <= digit_swaps  # a checksum-less protocol cannot catch these
    assert stats.bad_format > 0 and stats.timeouts > 0 and stats.balanced()
    print(f"\nodometer: {len(recs)} accepted of {twin.polls} polls, {len(inj.corrupted)} bytes corrupted, "
          f"{digit_swaps} digit->digit, {len(wrong)} wrong accepted, implausible {stats.extra['implausible']}")


# ------------------------------------------------------------------ gauge
def test_gauge_line_format_and_checksum():
    line = gauge.format_line(7, 123456, 1.43512)
    assert line.startswith(b"$GG,7,123456,1435.12,0*") and line.endswith(b"\r\n")
    rec = gauge.decode_line(line.decode().strip())
    assert rec.gauge_m == pytest.approx(1.43512) and rec.seq == 7 and rec.t_device_ms == 123456
    with pytest.raises(ChecksumError):
        gauge.decode_line(line.decode().strip().replace("1435.12", "1435.13"))


def test_gauge_through_pty_with_faults_and_replay(tmp_path):
    n = 3000
    t = np.arange(n) / 100.0
    g = 1.435 + 0.003 * np.sin(t)
    twin = GaugeTwin(t, g, realtime=False,
                     faults=Faults(corrupt_rate=5e-4, drop_rate=2e-4, garbage_rate=0.1, seed=9))
    stats = Stats()
    link = SerialLink(twin.port, gauge.GaugeParser(stats), "gauge", raw_log=tmp_path / "g.rawlog")
    link.open()
    link.start()
    twin.start()
    wait_until(lambda: twin.lines_sent >= n and link.snapshot().bytes_in >= twin.bytes_sent, 20.0)
    link.stop()
    twin.stop()
    recs = link.drain()
    # which lines were hit by a fault (offsets in the clean stream); harmless faults: a burst
    # inserted at a line start, the CR dropped or turned into LF (the LF still ends the line)
    ends = np.cumsum([len(x) for x in twin.lines])
    starts = {0} | set(ends[:-1].tolist())
    cr = set((ends - 2).tolist())
    inj = twin.injector
    bad = [o for o, to in zip(inj.corrupted, inj.corrupted_to) if not (o in cr and to == 0x0A)]
    bad += [o for o in inj.dropped if o not in cr]
    bad += [o for o, _ in inj.garbage if o not in starts]
    hit = set(np.searchsorted(ends, np.array(bad, int), side="right").tolist())
    good = [k for k in range(n) if k not in hit]
    assert [r.seq for r in recs] == good
    assert np.allclose([r.gauge_m for r in recs], np.round(g[good] * 1e5) / 1e5, atol=1e-9)
    assert stats.extra["lines_missing"] == n - len(good) - (n - 1 - good[-1]) - good[0]
    assert stats.bytes_in == twin.bytes_sent and stats.balanced()
    rep, rst = replay_gauge(tmp_path / "g.rawlog")
    assert rep == recs


def test_odometer_unplug_replug_keeps_counts_and_distance_continuous(tmp_path):
    cfg = encoder.OdometerConfig(bits=16, rate_hz=100.0)
    n = 4000
    t = np.arange(n) / cfg.rate_hz
    twin = OdometerTwin(t, 0.5 * t, cfg, offset_counts=65000, mode="index", link_path=tmp_path / "odo-by-id")
    link, stats = _odo_link(twin, cfg)
    poller = encoder.OdometerPoller(link, cfg).start()
    time.sleep(0.4)
    twin.disappear(0.3)
    wait_until(lambda: link.snapshot().frames_ok >= 60, 20.0, 0.02)
    poller.stop()
    link.stop()
    twin.stop()
    recs = link.drain()
    assert stats.reconnects == 1 and len(recs) >= 60
    counts = np.array([r.count1 for r in recs])
    # every reading is one the twin sent, in order; distance never goes backwards over the gap
    sent = np.array(twin.sent_counts)
    pos = [int(np.flatnonzero(sent == c)[0]) for c in counts]
    assert np.all(np.diff(pos) > 0)
    d = encoder.distance_m(counts, cfg)
    assert np.all(np.diff(d) >= 0)
    assert d[-1] == pytest.approx((pos[-1] - pos[0]) * 0.5 / cfg.rate_hz, abs=cfg.metres_per_count)


# ------------------------------------------------------------------ speed gate anchoring
def _feed(parser, counts, rate_hz, bits=32):
    out = []
    for k, c in enumerate(counts):
        out += parser.feed(encoder.format_read_reply(int(c), 0, bits), k / rate_hz)
    return out


def test_counter_reset_without_reconnect_reanchors_and_distance_carries_on():
    cfg = encoder.OdometerConfig(rate_hz=100.0)
    stats = Stats()
    counts = [0, 10, 20, 30, 5_000_000, 5_000_010, 5_000_020, 5_000_030]
    recs = _feed(encoder.EncoderParser(stats, cfg), counts, cfg.rate_hz)
    # 0 and 10 wait for confirmation; 5000000 and 5000010 are rejected until three agree
    assert [r.count1 for r in recs] == [20, 30, 5_000_020, 5_000_030]
    assert [r.segment for r in recs] == [0, 0, 1, 1]
    ex = stats.extra
    assert (ex["unconfirmed"], ex["implausible"], ex["reanchors"]) == (2, 2, 1) and stats.balanced()
    d = encoder.distance_m([r.count1 for r in recs], cfg, [r.segment for r in recs])
    assert np.allclose(d / cfg.metres_per_count, [0, 10, 10, 20])


@given(st.integers(0, 2**32 - 1), st.integers(0, 30), st.sets(st.integers(0, 59), max_size=12),
       st.integers(10**5, 2**31))
@settings(max_examples=60, deadline=None)
def test_no_corrupt_reading_is_accepted_and_no_good_one_lost_once_anchored(c0, v, corrupt, jump):
    cfg = encoder.OdometerConfig(rate_hz=100.0)
    bad = {k for k in corrupt if k - 1 not in corrupt}  # isolated corruptions (no two in a row)
    true = (c0 + v * np.arange(60)) % 2**32
    sent = true.copy()
    for k in bad:
        sent[k] = (true[k] + jump) % 2**32  # a high digit changed: far beyond the speed gate
    stats = Stats()
    recs = _feed(encoder.EncoderParser(stats, cfg), sent, cfg.rate_hz)
    # the first reading accepted is the third of the first three good readings in a row
    first = next(k for k in range(2, 60) if not {k - 2, k - 1, k} & bad)
    expect = [int(true[k]) for k in range(first, 60) if k not in bad]
    assert [r.count1 for r in recs] == expect
    assert stats.extra["implausible"] == len([k for k in bad if k > first]) and stats.extra["reanchors"] == 0


def test_corrupt_first_reply_through_pty_does_not_lock_the_odometer_out():
    cfg = encoder.OdometerConfig(bits=32, rate_hz=200.0)
    n = 300
    t = np.arange(n) / cfg.rate_hz
    dist = 0.8 * t
    dist[0] = 4000.0  # first reply corrupt: a high digit changed (the protocol has no checksum)
    twin = OdometerTwin(t, dist, cfg, offset_counts=123_456, mode="index")
    link, stats = _odo_link(twin, cfg)
    recs = _poll_until(twin, link, cfg, lambda: twin.polls >= n, reply_timeout_s=2.0)
    counts = [r.count1 for r in recs]
    # polls 0 (corrupt), 1 and 2 are withheld; from poll 3 on every reading is accepted
    assert counts == twin.sent_counts[3: 3 + len(counts)] and len(counts) >= n - 3
    assert stats.extra["unconfirmed"] == 3 and stats.extra["implausible"] == 0 and stats.balanced()
    d = encoder.distance_m(counts, cfg)
    assert d[n - 4] == pytest.approx(dist[n - 1] - dist[3], abs=cfg.metres_per_count)  # poll n-1


def test_power_cycled_unplug_resets_the_counter_new_segment_distance_continues(tmp_path):
    cfg = encoder.OdometerConfig(bits=32, rate_hz=100.0)
    n = 4000
    t = np.arange(n) / cfg.rate_hz
    twin = OdometerTwin(t, 0.5 * t, cfg, offset_counts=3_000_000, mode="index", link_path=tmp_path / "odo-by-id")
    link, stats = _odo_link(twin, cfg, tmp_path / "odo.rawlog")
    poller = encoder.OdometerPoller(link, cfg).start()
    time.sleep(0.4)
    twin.disappear(0.3, power_cycle=True)
    wait_until(lambda: len(twin.sent_counts) >= (twin.resets or [10**9])[0] + 40, 20.0, 0.02)
    poller.stop()
    link.stop()
    twin.stop()
    recs = link.drain()
    assert stats.reconnects == 1 and len(twin.resets) == 1
    r = twin.resets[0]
    sent = np.array(twin.sent_counts)
    assert sent[r] == 0  # the module restarted its count
    before = [x for x in recs if x.segment == 0]
    after = [x for x in recs if x.segment == 1]
    assert stats.extra["counter_resets"] == 1 and stats.extra["reanchors"] == 0
    assert len(before) > 10 and len(after) >= 30
    # replies to polls answered before the port was re-opened are lost (as on a real unplug);
    # of those that arrive, the first two are withheld, then every reading is accepted
    a0 = r + int(np.flatnonzero(sent[r:] == after[0].count1)[0])
    assert a0 >= r + 2 and stats.extra["unconfirmed"] == 4  # 2 at the start, 2 after the reset
    assert [x.count1 for x in after] == sent[a0: a0 + len(after)].tolist()
    c = [x.count1 for x in recs]
    d = encoder.distance_m(c, cfg, [x.segment for x in recs]) / cfg.metres_per_count
    k = len(before)
    assert np.all(np.diff(d) >= 0) and d[k] == d[k - 1]  # the reset is not a distance jump
    assert d[-1] - d[k] == after[-1].count1 - after[0].count1
    assert stats.balanced()
    rep, rst = replay_encoder(tmp_path / "odo.rawlog", cfg)  # the reconnect mark is in the log
    assert rep == recs and rst.reconnects == 1 and rst.extra == stats.extra


def test_odometer_late_and_missing_replies_in_order_and_counted():
    cfg = encoder.OdometerConfig(bits=32, rate_hz=100.0)
    n = 150
    t = np.arange(n) / cfg.rate_hz
    twin = OdometerTwin(t, 0.5 * t, cfg, offset_counts=777, mode="index",
                        faults=Faults(delay_rate=0.05, delay_s=0.15, missing_rate=0.03, seed=8))
    link, stats = _odo_link(twin, cfg)
    recs = _poll_until(twin, link, cfg, lambda: twin.polls >= n, timeout_s=30.0, settle_s=0.3, reply_timeout_s=0.08)  # the last late reply
    answered = [c for k, c in enumerate(twin.sent_counts) if k not in set(twin.missing)]
    assert len(twin.delayed) >= 3 and len(twin.missing) >= 2
    # late replies come in order: every answered poll arrives, none twice, none out of order
    assert [r.count1 for r in recs] == answered[2:]  # the first two wait for the gate's anchor
    # a poll left unanswered, or answered 0.15 s late, times out (0.08 s)
    assert stats.timeouts >= len(twin.missing) + len(twin.delayed)
    assert stats.extra["implausible"] == 0 and stats.balanced()
    # the late replies arrive late: their host times show a gap of about delay_s
    dt = np.diff([r.t_host_s for r in recs])
    assert np.sum(dt > 0.12) >= len(twin.delayed) - 1


def test_gauge_unplug_replug_keeps_lines_and_counts_the_gap(tmp_path):
    n = 600
    t = np.arange(n) / 100.0
    g = 1.435 + 0.001 * np.sin(t)
    twin = GaugeTwin(t, g, link_path=tmp_path / "gauge-by-id")
    stats = Stats()
    link = SerialLink(twin.port, gauge.GaugeParser(stats), "gauge", raw_log=tmp_path / "g.rawlog")
    link.open()
    link.start()
    twin.start()
    time.sleep(1.0)
    twin.disappear(0.5)
    wait_until(lambda: twin.lines_sent >= n, 20.0, 0.02)
    time.sleep(0.2)
    link.stop()
    twin.stop()
    recs = link.drain()
    seq = [r.seq for r in recs]
    assert stats.reconnects == 1 and len(seq) > 300
    # lines before and after the unplug are all kept, in order; the lines written while the
    # port was gone are lost and show as one gap in the line counter
    assert np.all(np.diff(seq) > 0) and seq[-1] == n - 1
    assert stats.extra["seq_gaps"] == 1 and stats.extra["lines_missing"] == n - len(seq) - seq[0]
    assert np.allclose([r.gauge_m for r in recs], np.round(g[seq] * 1e5) / 1e5, atol=1e-9)
    assert stats.bad_checksum == 0 and stats.balanced()
    rep, _ = replay_gauge(tmp_path / "g.rawlog")
    assert rep == recs


def test_a_second_program_on_an_open_port_is_refused_not_given_half_the_bytes():
    """Two sessions (or a session and `trolley devices record`) on one port each got a share of
    its bytes, silently (hunt27a): the port is now opened exclusively, and the second open fails
    with the lock's reason, naming the device and the port."""
    import os

    from drivers.serialport import PortNotFound

    master, slave = os.openpty()
    path = os.ttyname(slave)
    first = SerialLink(path, gauge.GaugeParser(Stats()), name="gauge")
    second = SerialLink(path, gauge.GaugeParser(Stats()), name="gauge")
    try:
        first.open(timeout_s=1.0)
        with pytest.raises(PortNotFound, match=f"gauge: cannot open {path}: .*exclusively lock"):
            second.open(timeout_s=0.1)
    finally:
        first.stop()
        os.close(master)
        os.close(slave)
