"""NovAtel RAWIMUSX: CRC-32, published examples, scaling, vectorised parser, streaming."""
from __future__ import annotations

import zlib

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from drivers import novatel as nv
from drivers.stats import Stats

# Published examples (docs.novatel.com RAWIMUSX / RAWIMUS pages; protocols.md 4.1)
XA = ("%RAWIMUSXA,2209,491674.014;04,41,2209,491674.013699,ea59fe00,329308016,-2706935,4508389,"
      "196192,417138,-1000837*038422a7")
SA = ("%RAWIMUSA,2209,491612.254;2209,491612.253588,ea5afe00,329303960,-2512321,4410363,309705,"
      "607017,-1009773*1fb76c28")


def _zlib_based(data: bytes) -> int:
    # init 0 / no final XOR expressed through zlib's init ~0 / xorout ~0 (an independent method)
    return zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF


def test_crc32_published_examples_and_not_zlib():
    for line, crc in ((XA, 0x038422A7), (SA, 0x1FB76C28)):
        body = line[1: line.index("*")].encode()
        assert nv.crc32(body) == crc
        assert zlib.crc32(body) != crc


@given(st.lists(st.binary(min_size=7, max_size=7), min_size=1, max_size=20))
@settings(max_examples=40, deadline=None)
def test_crc32_vectorised_equals_scalar_and_zlib(rows):
    m = np.frombuffer(b"".join(rows), np.uint8).reshape(len(rows), 7)
    got = nv.crc32_rows(m)
    assert [int(x) for x in got] == [nv.crc32(r) for r in rows] == [_zlib_based(r) for r in rows]


def test_published_rawimusxa_scales_to_gravity():
    fr = nv.parse_rawimusxa(XA)
    w, f = fr.to_si(nv.imu_scale(41))
    # protocols.md worked check: Z = 9.855 m/s^2, -Y = -0.081, X = 0.135; gyro Z 0.02395 deg/s
    assert f[0, 2] == pytest.approx(9.855, abs=5e-4)
    assert f[0, 1] == pytest.approx(0.081, abs=5e-4)  # Y restored from the stored -Y
    assert f[0, 0] == pytest.approx(0.135, abs=5e-4)
    assert np.degrees(w[0, 2]) == pytest.approx(0.02395, abs=5e-5)
    assert np.degrees(w[0, 1]) == pytest.approx(-0.0509, abs=5e-4)
    assert fr.imu_info[0] == 4 and fr.imu_type[0] == 41


def test_rawimusxa_roundtrip_and_bad_crc():
    line = nv.format_rawimusxa(2300, 1234.5, [1, -2, 3], [4, -5, 6], imu_type=26, imu_info=1)
    fr = nv.parse_rawimusxa(line)
    assert fr.gyro_counts.tolist() == [[1, -2, 3]] and fr.accel_counts.tolist() == [[4, -5, 6]]
    bad = line.replace(",4,", ",5,", 1) if ",4," in line else line[:-6] + "0000\r\n"
    with pytest.raises(ValueError):
        nv.parse_rawimusxa(bad)


def test_increment_scale_hand_computed():
    # ISA-100C: 1e-9 rad per count at 200 Hz -> 2e-7 rad/s per count; 2e-8 m/s -> 4e-6 m/s^2
    fr = nv.ImuFrames(np.zeros(1), np.zeros(1, int), np.zeros(1), np.zeros(1, np.uint8),
                      np.full(1, 26, np.uint8), np.zeros(1, np.uint32),
                      np.array([[1000, 0, 0]]), np.array([[0, 0, -2451662]]))
    w, f = fr.to_si(nv.imu_scale(26))
    assert w[0, 0] == pytest.approx(2e-4) and f[0, 2] == pytest.approx(-9.806648)


def test_axis_map():
    assert np.array_equal(nv.axis_matrix(), np.eye(3))
    c = nv.axis_matrix("y,-x,-z")
    assert c @ np.array([1.0, 2.0, 3.0]) == pytest.approx([2.0, -1.0, -3.0])
    for bad in ("x,y", "x,x,z", "a,b,c"):
        with pytest.raises(ValueError):
            nv.axis_matrix(bad)


def _stream(n, seed=0, imu_info=0):
    rng = np.random.default_rng(seed)
    g = rng.integers(-2**31 + 1, 2**31 - 1, (n, 3))
    a = rng.integers(-2**31 + 1, 2**31 - 1, (n, 3))
    sow = 1000.0 + np.arange(n) / 200.0
    return nv.encode_rawimusxb(2300, sow, g, a, 26, imu_info), g, a, sow


def test_binary_roundtrip_sign_and_order():
    buf, g, a, sow = _stream(50)
    # field order on the wire: Z, -Y, X (accel then gyro)
    rec = np.frombuffer(buf, nv.FRAME_DTYPE)
    assert np.array_equal(rec["acc_z"], a[:, 2]) and np.array_equal(rec["gyr_ny"], -g[:, 1])
    res = nv.parse_rawimusxb_buffer(buf)
    fr = nv._frames_from_rows(res.rows, np.zeros(len(res.rows)))
    assert np.array_equal(fr.gyro_counts, g) and np.array_equal(fr.accel_counts, a)
    assert np.array_equal(fr.sow_s, sow) and res.bad_crc == 0 and res.keep_from == len(buf)


@given(st.lists(st.integers(1, 700), min_size=1, max_size=60), st.integers(0, 10_000))
@settings(max_examples=40, deadline=None)
def test_stream_split_anywhere_identical(cuts, seed):
    buf, g, a, _ = _stream(40, seed)
    stats = Stats()
    p = nv.RawImuParser(stats, 200.0)
    out, pos = [], 0
    for c in cuts:
        out.append(p.feed(buf[pos: pos + c], float(pos)))
        pos += c
    out.append(p.feed(buf[pos:], float(pos)))
    fr = nv.ImuFrames.concat(out)
    assert np.array_equal(fr.gyro_counts, g) and np.array_equal(fr.accel_counts, a)
    assert stats.frames_ok == 40 and stats.bytes_discarded == 0 and stats.balanced()


@given(st.integers(0, 10_000))
@settings(max_examples=30, deadline=None)
def test_garbage_corruption_drops_recover_all_good_frames(seed):
    rng = np.random.default_rng(seed)
    n = 60
    buf, g, a, sow = _stream(n, seed)
    frames = [bytearray(buf[i * 56:(i + 1) * 56]) for i in range(n)]
    damaged = set()
    pieces = []
    for i, fr in enumerate(frames):
        r = rng.random()
        if r < 0.1:
            fr[int(rng.integers(0, 56))] ^= int(rng.integers(1, 256))
            damaged.add(i)
        elif r < 0.15:
            del fr[int(rng.integers(0, 56))]
            damaged.add(i)
        if rng.random() < 0.15:  # garbage burst between frames, with fake syncs in it
            pieces.append(bytes(rng.integers(0, 256, int(rng.integers(1, 80)), dtype=np.uint8)) + b"\xaa\x44\x13\x28")
        pieces.append(bytes(fr))
    data = b"".join(pieces)
    stats = Stats()
    p = nv.RawImuParser(stats)
    out = [p.feed(data[k: k + 97], 0.0) for k in range(0, len(data), 97)] + [p.flush()]
    got = nv.ImuFrames.concat(out)
    good = [i for i in range(n) if i not in damaged]
    # nothing corrupt accepted: each accepted frame is a sent frame, in order; every good frame
    # is recovered (a damaged frame may still pass when its content survived, e.g. a dropped
    # last CRC byte replaced by an equal garbage byte: then it is genuine)
    idx = np.searchsorted(sow, got.sow_s)
    assert np.all(idx < n) and np.array_equal(sow[np.minimum(idx, n - 1)], got.sow_s) and np.all(np.diff(idx) > 0)
    assert np.array_equal(got.gyro_counts, g[idx]) and np.array_equal(got.accel_counts, a[idx])
    assert set(good) <= set(idx.tolist())
    assert stats.frames_ok == len(idx)
    assert stats.bytes_in == len(data) and stats.balanced() and stats.bytes_pending == 0
    assert stats.bytes_ok == 56 * len(idx)


def test_error_bits_and_time_gaps_counted():
    buf, *_ = _stream(20, imu_info=np.array([0] * 18 + [1, 1], np.uint8))
    cut = buf[:5 * 56] + buf[8 * 56:]  # frames 5, 6, 7 missing
    stats = Stats()
    nv.RawImuParser(stats, 200.0).feed(cut, 0.0)
    assert stats.extra["imu_error_frames"] == 2
    assert stats.extra["time_gaps"] == 1 and stats.extra["frames_missing"] == 3


@given(st.sampled_from([100.0, 125.0, 200.0, 400.0, 1000.0]), st.integers(1, 19), st.integers(1, 6),
       st.integers(1, 97), st.integers(0, 603000))
@settings(max_examples=30, deadline=None)
def test_rate_inferred_from_time_steps_counts_gaps_without_a_given_rate(rate, at, missing, read, sow0):
    # frames at..at+missing-1 are missing, inside the frames the rate is inferred from
    n = 60
    sow = sow0 + np.arange(n) / rate
    keep = np.r_[0:at, at + missing:n]
    buf = nv.encode_rawimusxb(2300, sow[keep], np.ones((keep.size, 3)), np.ones((keep.size, 3)))
    stats, given_rate = Stats(), Stats()
    p = nv.RawImuParser(stats)
    out = [p.feed(buf[k: k + read], 0.0) for k in range(0, len(buf), read)]
    nv.RawImuParser(given_rate, rate).feed(buf, 0.0)
    assert len(nv.ImuFrames.concat(out)) == keep.size
    assert p.rate == rate and stats.extra["rate_hz"] == rate  # snapped to whole hertz exactly
    assert stats.extra["time_gaps"] == 1 and stats.extra["frames_missing"] == missing
    assert stats.extra == given_rate.extra


def test_rate_inference_needs_distinct_times():
    with pytest.raises(ValueError, match="two distinct"):
        nv.rate_from_times([5.0, 5.0])
    assert nv.rate_from_times([0.0, 0.008, 0.016, 0.04]) == 125.0  # median step, not the mean


def test_ascii_log_parse_matches_binary_and_rejects_bad_lines():
    buf, g, a, sow = _stream(30, 5)
    lines = [nv.format_rawimusxa(2300, s, gi, ai) for s, gi, ai in zip(sow, g, a)]
    lines[3] = lines[3].replace("*", "0*", 1)  # malformed
    lines[7] = lines[7][:-5] + ("0" if lines[7][-5] != "0" else "1") + "\r\n"  # CRC digit changed
    text = "#COMMENT line\r\n" + "".join(lines)
    stats = Stats()
    fr = nv.parse_rawimusxa_lines(text, stats)
    keep = [i for i in range(30) if i not in (3, 7)]
    assert np.array_equal(fr.gyro_counts, g[keep]) and np.array_equal(fr.accel_counts, a[keep])
    assert np.allclose(fr.sow_s, sow[keep], atol=5e-7)
    assert (stats.frames_ok, stats.bad_checksum, stats.bad_format) == (28, 1, 1)


@given(st.integers(1, 60), st.integers(1, 30), st.integers(0, 1000))
@settings(max_examples=30, deadline=None)
def test_crc32_rows_any_width(width, n, seed):
    rows = np.random.default_rng(seed).integers(0, 256, (n, width)).astype(np.uint8)
    assert [int(x) for x in nv.crc32_rows(rows)] == [_zlib_based(r.tobytes()) for r in rows]


def _other_log(body_len, seed):
    """A valid short-header log of another type (e.g. INSPVAS, id 508) with its own length."""
    rng = np.random.default_rng(seed)
    hdr = nv.SYNC_SHORT + bytes([body_len]) + (508).to_bytes(2, "little") + (2300).to_bytes(2, "little") + (5).to_bytes(4, "little")
    msg = hdr + rng.integers(0, 256, body_len, dtype=np.uint8).tobytes()
    return msg + nv.crc32(msg).to_bytes(4, "little")


@given(st.integers(0, 10_000))
@settings(max_examples=30, deadline=None)
def test_other_logs_on_the_port_are_skipped_not_counted_as_bad(seed):
    rng = np.random.default_rng(seed)
    buf, g, a, _ = _stream(40, seed)
    pieces, n_other, other_bytes = [], 0, 0
    damaged = set()
    for i in range(40):
        fr = bytearray(buf[i * 56:(i + 1) * 56])
        if rng.random() < 0.1:  # corrupt the length byte: must end as one bad CRC
            fr[3] ^= int(rng.integers(1, 256))
            damaged.add(i)
        pieces.append(bytes(fr))
        if rng.random() < 0.3:
            m = _other_log(int(rng.choice([20, 40, 88, 200])), seed + i)
            pieces.append(m)
            n_other += 1
            other_bytes += len(m)
    data = b"".join(pieces)
    stats = Stats()
    p = nv.RawImuParser(stats)
    out = [p.feed(data[k: k + 61], 0.0) for k in range(0, len(data), 61)] + [p.flush()]
    got = nv.ImuFrames.concat(out)
    good = [i for i in range(40) if i not in damaged]
    assert np.array_equal(got.gyro_counts, g[good])
    assert stats.extra["other_msgs"] == n_other and stats.bad_checksum == len(damaged)
    assert stats.bytes_ok == 56 * len(good) + other_bytes and stats.balanced()


@given(st.integers(0, 10_000), st.lists(st.integers(1, 150), min_size=1, max_size=80))
@settings(max_examples=30, deadline=None)
def test_damaged_stream_parse_is_independent_of_read_sizes(seed, cuts):
    rng = np.random.default_rng(seed)
    buf, *_ = _stream(50, seed)
    b = bytearray(buf)
    for _ in range(5):
        b[int(rng.integers(0, len(b)))] ^= int(rng.integers(1, 256))
    for _ in range(3):
        del b[int(rng.integers(0, len(b)))]
    for _ in range(3):
        k = int(rng.integers(0, len(b)))
        b[k:k] = _other_log(int(rng.choice([20, 88, 200])), seed) if rng.random() < 0.5 else \
            rng.integers(0, 256, 30, dtype=np.uint8).tobytes() + nv.SYNC_SHORT

    def run(sizes):
        stats = Stats()
        p = nv.RawImuParser(stats, 200.0)
        out, pos = [], 0
        for c in sizes:
            out.append(p.feed(bytes(b[pos: pos + c]), 0.0))
            pos += c
        out += [p.feed(bytes(b[pos:]), 0.0), p.flush()]
        stats.bytes_pending = 0
        return nv.ImuFrames.concat(out).sow_s.tolist(), stats

    whole, s1 = run([])
    split, s2 = run(cuts)
    assert whole == split and s1 == s2 and s1.balanced()


def test_scale_table_covers_the_documented_types_with_their_factors():
    arcsec = np.pi / 180.0 / 3600.0
    ft = 0.3048
    # hand values of NovAtel's raw IMU scale factor table
    assert nv.imu_scale(1).gyro == 2.0**-33 and nv.imu_scale(1).accel == 2.0**-27 * ft
    assert nv.imu_scale(4).gyro == 2.0**-33 and nv.imu_scale(4).accel == 2.0**-26 * ft
    assert nv.imu_scale(13).gyro == pytest.approx(0.1 / 256 * arcsec, rel=1e-15)
    assert nv.imu_scale(13).accel == 0.05 / 2.0**15
    assert nv.imu_scale(16).gyro == 0.1 / (3600.0 * 256.0) and nv.imu_scale(16).accel == 0.05 / 2.0**15
    g370 = nv.imu_scale(61)
    assert g370.counts_are_rates and g370.gyro == pytest.approx(0.0151515 / 65536 * np.pi / 180, rel=1e-15)
    assert g370.accel == pytest.approx(0.4 / 65536 * 1e-3 * 9.80665, rel=1e-15)
    g320 = nv.imu_scale(62)
    assert g320.counts_are_rates and g320.rate_hz == 200.0
    assert (g320.gyro, g320.accel) == (nv.imu_scale(41).gyro, nv.imu_scale(41).accel)
    # names as NovAtel names the types
    assert nv.imu_scale(5).name == "HG1900-CA29" and nv.imu_scale(69).name == "HG4930-AN04-400Hz"
    assert nv.imu_scale(69).rate_hz == 400.0


def test_unknown_imu_type_is_a_clear_error_not_a_key_error():
    with pytest.raises(nv.UnknownImuType, match=r"IMU type 99.*--imu-type") as e:
        nv.imu_scale(99)
    assert not isinstance(e.value, KeyError) and "13 iMAR-FSAS" in str(e.value)


def test_rawimusa_lines_are_counted_as_other_messages():
    # the RAWIMUSA example of NovAtel's documentation (protocols.md 4.1): a valid log, not RAWIMUSXA
    rawimusa = ("%RAWIMUSA,2209,491612.254;2209,491612.253588,ea5afe00,329303960,-2512321,4410363,"
                "309705,607017,-1009773*1fb76c28")
    assert nv.crc32(rawimusa[1:rawimusa.rindex("*")].encode()) == 0x1FB76C28
    xa = nv.format_rawimusxa(2209, 491612.254, [1, 2, 3], [4, 5, 6])
    stats = Stats()
    fr = nv.parse_rawimusxa_lines("# a comment\r\n" + rawimusa + "\r\n" + xa + "#BESTPOSA,COM1,0*00\r\n", stats)
    assert len(fr) == 1 and stats.frames_ok == 1
    assert stats.extra["other_msgs"] == 2 and stats.bad_format == 0
