"""NovAtel OEM7 RAWIMUSX log: binary short-header RAWIMUSXB and ASCII %RAWIMUSXA, CRC-32, scales.

Every NovAtel constant of this project lives here. Frame layout (protocols.md section 4.1, from
docs.novatel.com OEM7 "Description of Short Headers" and "RAWIMUSX"):

    offset  type      field
    0       uchar[3]  sync AA 44 13
    3       uchar     body length (40)
    4       ushort    message id (1462)
    6       ushort    GPS week
    8       long      milliseconds of week
    12      uchar     IMU info (bit 0: IMU error)
    13      uchar     IMU type
    14      ushort    GPS week
    16      double    seconds of week
    24      ulong     IMU status
    28      long x 6  Z accel, -(Y accel), X accel, Z gyro, -(Y gyro), X gyro  (increments)
    52      ulong     CRC-32 over bytes 0..51

CRC-32: reflected polynomial 0xEDB88320 with initial value 0 and no final XOR (NovAtel
``CalculateBlockCRC32``): zlib's CRC-32 with its initial value and final XOR undone
(:func:`crc32`). The vectorised parser checks the CRC of every sync candidate of a buffer at
once: one table look-up per byte column across all candidates.

Counts to SI: ``value = count * scale * rate_hz`` (counts are increments over one IMU period),
except for IMUs whose counts are already rates (Epson G320N). The Y axis is stored negated.
"""
from __future__ import annotations

import re
import zlib
from dataclasses import dataclass

import numpy as np

SYNC_SHORT = b"\xaa\x44\x13"
MSG_ID_RAWIMUSX = 1462
HEADER_LEN = 12
BODY_LEN = 40
CRC_LEN = 4
FRAME_LEN = HEADER_LEN + BODY_LEN + CRC_LEN  # 56
CRC32_POLY = 0xEDB88320
IMU_INFO_ERROR_BIT = 0x01
SECONDS_PER_WEEK = 604800.0
ASCII_NAME = "RAWIMUSXA"

_FT = 0.3048
_DEG = np.pi / 180.0
_ARCSEC = _DEG / 3600.0
_G = 9.80665


def _crc32_table() -> np.ndarray:
    t = np.arange(256, dtype=np.uint32)
    for _ in range(8):
        t = np.where(t & 1, (t >> np.uint32(1)) ^ np.uint32(CRC32_POLY), t >> np.uint32(1))
    return t.astype(np.uint32)


CRC32_TABLE: np.ndarray = _crc32_table()


def _crc32_table16() -> np.ndarray:
    # two byte-steps at once: the CRC is linear, so feeding bytes b0, b1 equals XOR-ing the
    # 16-bit word (b0 | b1 << 8) into the state and running two steps with zero input
    s = np.arange(65536, dtype=np.uint32)
    for _ in range(2):
        s = CRC32_TABLE[s & np.uint32(0xFF)] ^ (s >> np.uint32(8))
    return s


CRC32_TABLE16: np.ndarray = _crc32_table16()

#: numpy layout of one RAWIMUSXB frame (little-endian, packed).
FRAME_DTYPE = np.dtype([
    ("sync", "u1", (3,)), ("body_len", "u1"), ("msg_id", "<u2"), ("hdr_week", "<u2"),
    ("hdr_ms", "<i4"), ("imu_info", "u1"), ("imu_type", "u1"), ("week", "<u2"),
    ("sow", "<f8"), ("status", "<u4"), ("acc_z", "<i4"), ("acc_ny", "<i4"), ("acc_x", "<i4"),
    ("gyr_z", "<i4"), ("gyr_ny", "<i4"), ("gyr_x", "<i4"), ("crc", "<u4"),
])
assert FRAME_DTYPE.itemsize == FRAME_LEN


def crc32(data: bytes) -> int:
    """NovAtel CRC-32 of ``data`` (init 0, no final XOR).

    NovAtel's ``CalculateBlockCRC32`` is the reflected 0xEDB88320 CRC with init 0 and no final
    XOR; zlib's CRC-32 is the same polynomial with init and final XOR 0xFFFFFFFF, so starting
    zlib from 0xFFFFFFFF and XOR-ing its result undoes both (zlib runs in C: 0.15 us against 3.3 us
    for a table loop in Python over a 52-byte frame).

    References
    ----------
    NovAtel OEM7 firmware reference, "32-Bit CRC"; protocols.md section 4.1.
    """
    return zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF


def crc32_rows(rows: np.ndarray) -> np.ndarray:
    """NovAtel CRC-32 of every row of a (n, m) uint8 array, vectorised across rows.

    One table look-up per 16-bit column for all rows at once (m/2 numpy steps, not n*m).
    """
    rows = np.asarray(rows, dtype=np.uint8)
    crc = np.zeros(rows.shape[0], dtype=np.uint32)
    m = rows.shape[1]
    if m >= 2:  # 16 bits per step with the 64K-entry table (half the look-ups)
        words = np.ascontiguousarray(rows[:, : m - m % 2]).view("<u2")
        mask16, sixteen = np.uint32(0xFFFF), np.uint32(16)
        for j in range(words.shape[1]):
            crc = CRC32_TABLE16[(crc ^ words[:, j]) & mask16] ^ (crc >> sixteen)
    mask, eight = np.uint32(0xFF), np.uint32(8)
    for j in range(m - m % 2, m):
        crc = CRC32_TABLE[(crc ^ rows[:, j]) & mask] ^ (crc >> eight)
    return crc


# ----------------------------------------------------------------------------- scale table
@dataclass(frozen=True)
class ImuScale:
    """How one IMU type's counts become SI.

    Attributes
    ----------
    name : IMU model.
    gyro : rad per count (an angle increment), or rad/s per count if ``counts_are_rates``.
    accel : m/s per count (a velocity increment), or m/s^2 per count if ``counts_are_rates``.
    rate_hz : IMU data rate (the increments are over 1/rate_hz).
    counts_are_rates : the counts are rates, not increments (Epson G320N).
    """

    name: str
    gyro: float
    accel: float
    rate_hz: float
    counts_are_rates: bool = False


_HG_AG58 = (2.0**-33, 2.0**-27 * _FT)
_HG_AG62 = (2.0**-33, 2.0**-26 * _FT)
_KVH = (0.1 / (3600.0 * 256.0), 0.05 / 2.0**15)
#: IMU type number (RAWIMUSX "IMU Type") -> scale, names as NovAtel's INSCONFIG / oem7_imu.hpp
#: spell them, scales from NovAtel's raw IMU scale factor table as the NovAtel ROS driver codes it
#: (oem7_imu.cpp; protocols.md section 4.1). Rates are the types' nominal SPAN data rates. The
#: KVH gyro unit (deg or rad per count) is UNCONFIRMED; taken as rad, as the NovAtel driver does.
#: The ROS driver's feet-to-metres factor is 1/3.2808; the international foot 0.3048 m is exact.
IMU_SCALES: dict[int, ImuScale] = {
    1: ImuScale("HG1700-AG11", *_HG_AG58, 100.0),
    4: ImuScale("HG1700-AG17", *_HG_AG62, 100.0),
    5: ImuScale("HG1900-CA29", *_HG_AG58, 100.0),
    8: ImuScale("LN200", 2.0**-19, 2.0**-14, 200.0),
    11: ImuScale("HG1700-AG58", *_HG_AG58, 100.0),
    12: ImuScale("HG1700-AG62", *_HG_AG62, 100.0),
    13: ImuScale("iMAR-FSAS", 0.1 / 2.0**8 * _ARCSEC, 0.05 / 2.0**15, 200.0),
    16: ImuScale("KVH-COTS", *_KVH, 100.0),
    20: ImuScale("HG1930-AA99", *_HG_AG58, 100.0),
    26: ImuScale("ISA-100C", 1.0e-9, 2.0e-8, 200.0),
    27: ImuScale("HG1900-CA50", *_HG_AG58, 100.0),
    28: ImuScale("HG1930-CA50", *_HG_AG58, 100.0),
    31: ImuScale("ADIS16488", 720.0 / 2.0**31 * _DEG, 200.0 / 2.0**31, 200.0),
    32: ImuScale("STIM300", 2.0**-21 * _DEG, 2.0**-22, 125.0),
    33: ImuScale("KVH1750", *_KVH, 200.0),
    41: ImuScale("EG320N", 0.008 / 2.0**16 * _DEG, 0.2 / 2.0**16 * 1e-3 * _G, 125.0, True),
    52: ImuScale("uIMU", 1.0e-9, 2.0e-8, 200.0),
    56: ImuScale("STIM300-D", 2.0**-21 * _DEG, 2.0**-22, 125.0),
    58: ImuScale("HG4930-AN01", 2.0**-33, 2.0**-29, 100.0),
    61: ImuScale("EG370N", 0.0151515 / 2.0**16 * _DEG, 0.4 / 2.0**16 * 1e-3 * _G, 200.0, True),
    62: ImuScale("EG320N-200Hz", 0.008 / 2.0**16 * _DEG, 0.2 / 2.0**16 * 1e-3 * _G, 200.0, True),
    68: ImuScale("HG4930-AN04", 2.0**-33, 2.0**-29, 100.0),
    69: ImuScale("HG4930-AN04-400Hz", 2.0**-33, 2.0**-29, 400.0),
}


class UnknownImuType(ValueError):
    """RAWIMUSX frames of an IMU type that has no scale in :data:`IMU_SCALES`."""


def imu_scale(imu_type: int, rate_hz: float | None = None) -> ImuScale:
    """The scale of IMU type ``imu_type``, optionally at another data rate.

    Raises
    ------
    UnknownImuType : unknown IMU type (message names the type and what to pass instead).
    """
    if imu_type not in IMU_SCALES:
        known = ", ".join(f"{k} {v.name}" for k, v in sorted(IMU_SCALES.items()))
        raise UnknownImuType(
            f"unknown NovAtel IMU type {imu_type}: its scale factors are not known. Give the "
            f"number of a known type whose scale factors your IMU shares (NovAtel's raw IMU "
            f"scale factor table): --imu-type N for 'trolley devices', \"imu_type\": N in the "
            f"devices file of a field session. Known types: {known}")
    s = IMU_SCALES[imu_type]
    if rate_hz is None:
        return s
    return ImuScale(s.name, s.gyro, s.accel, float(rate_hz), s.counts_are_rates)


# ----------------------------------------------------------------------------- axis mapping
_AXIS_RE = re.compile(r"^\s*([+-]?)([xyz])\s*$")


def axis_matrix(spec: str = "x,y,z") -> np.ndarray:
    """Matrix C with ``v_frd = C @ v_imu`` from a spec like ``"x,-y,-z"``.

    The i-th token names the IMU axis (with sign) that becomes trolley FRD axis i. The default
    ``"x,y,z"`` is the identity (the IMU is mounted with its axes along the trolley's FRD).

    Raises
    ------
    ValueError : malformed spec or an axis used twice.
    """
    toks = spec.split(",")
    if len(toks) != 3:
        raise ValueError(f"axis map {spec!r}: need three comma-separated axes like 'x,-y,-z'")
    c = np.zeros((3, 3))
    used = set()
    for i, tok in enumerate(toks):
        m = _AXIS_RE.match(tok)
        if not m:
            raise ValueError(f"axis map {spec!r}: bad axis {tok!r} (use x, y, z with optional sign)")
        j = "xyz".index(m.group(2))
        if j in used:
            raise ValueError(f"axis map {spec!r}: axis {m.group(2)} used twice")
        used.add(j)
        c[i, j] = -1.0 if m.group(1) == "-" else 1.0
    return c


# ----------------------------------------------------------------------------- records
@dataclass
class ImuFrames:
    """A batch of decoded RAWIMUSX frames as arrays (one row per frame).

    Attributes
    ----------
    t_host_s : host monotonic time of the read that completed each frame.
    week, sow_s : GPS week and seconds of week from the body.
    imu_info, imu_type : IMU info byte (bit 0 = IMU error) and IMU type.
    status : IMU status word.
    gyro_counts, accel_counts : (n, 3) counts about/along the IMU's own x, y, z, with the sign
        of Y already restored.
    """

    t_host_s: np.ndarray
    week: np.ndarray
    sow_s: np.ndarray
    imu_info: np.ndarray
    imu_type: np.ndarray
    status: np.ndarray
    gyro_counts: np.ndarray
    accel_counts: np.ndarray

    def __len__(self) -> int:
        return int(self.sow_s.shape[0])

    @staticmethod
    def empty() -> "ImuFrames":
        """A batch with no frames."""
        z = np.zeros(0)
        return ImuFrames(z, z.astype(np.int64), z, z.astype(np.uint8), z.astype(np.uint8),
                         z.astype(np.uint32), np.zeros((0, 3), np.int64), np.zeros((0, 3), np.int64))

    @staticmethod
    def concat(batches: list["ImuFrames"]) -> "ImuFrames":
        """Join batches in order."""
        batches = [b for b in batches if len(b)]
        if not batches:
            return ImuFrames.empty()
        return ImuFrames(*(np.concatenate([getattr(b, f) for b in batches])
                           for f in ImuFrames.__dataclass_fields__))

    def gps_time_s(self) -> np.ndarray:
        """Continuous GPS time (week * 604800 + seconds of week)."""
        return self.week.astype(float) * SECONDS_PER_WEEK + self.sow_s

    def seconds_since(self, week0: int, sow0: float) -> np.ndarray:
        """Device time since (week0, sow0), without the precision loss of the absolute GPS time."""
        return (self.week - int(week0)).astype(float) * SECONDS_PER_WEEK + (self.sow_s - float(sow0))

    def to_si(self, scale: ImuScale, axes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Angular rate (rad/s) and specific force (m/s^2) in the trolley FRD frame.

        Parameters
        ----------
        scale : the IMU's scale (``imu_scale(type, rate)``).
        axes : matrix from ``axis_matrix`` (identity when None).

        Returns
        -------
        w_rad_s, f_m_s2 : (n, 3) arrays.
        """
        k = 1.0 if scale.counts_are_rates else scale.rate_hz
        w = self.gyro_counts * (scale.gyro * k)
        f = self.accel_counts * (scale.accel * k)
        if axes is not None:
            w = w @ np.asarray(axes).T
            f = f @ np.asarray(axes).T
        return w, f


def _frames_from_rows(rec: np.ndarray, t_host: np.ndarray) -> ImuFrames:
    gyro = np.stack([rec["gyr_x"], -rec["gyr_ny"].astype(np.int64), rec["gyr_z"]], axis=1).astype(np.int64)
    acc = np.stack([rec["acc_x"], -rec["acc_ny"].astype(np.int64), rec["acc_z"]], axis=1).astype(np.int64)
    return ImuFrames(np.asarray(t_host, float), rec["week"].astype(np.int64), rec["sow"].astype(float),
                     rec["imu_info"].copy(), rec["imu_type"].copy(), rec["status"].copy(), gyro, acc)


# ----------------------------------------------------------------------------- encoding
def counts_from_si(w_rad_s: np.ndarray, f_m_s2: np.ndarray, scale: ImuScale,
                   axes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :meth:`ImuFrames.to_si`: rounded counts about the IMU's x, y, z (Y not negated)."""
    w = np.atleast_2d(np.asarray(w_rad_s, float))
    f = np.atleast_2d(np.asarray(f_m_s2, float))
    if axes is not None:  # v_frd = C v_imu, C orthogonal -> v_imu = C^T v_frd
        w = w @ np.asarray(axes)
        f = f @ np.asarray(axes)
    k = 1.0 if scale.counts_are_rates else scale.rate_hz
    return np.rint(w / (scale.gyro * k)).astype(np.int64), np.rint(f / (scale.accel * k)).astype(np.int64)


def encode_rawimusxb(week: np.ndarray, sow_s: np.ndarray, gyro_counts: np.ndarray,
                     accel_counts: np.ndarray, imu_type: int = 26, imu_info: np.ndarray | int = 0,
                     status: np.ndarray | int = 0) -> bytes:
    """RAWIMUSXB frames for n samples, concatenated (vectorised).

    Parameters
    ----------
    week, sow_s : (n,) GPS week and seconds of week.
    gyro_counts, accel_counts : (n, 3) counts about the IMU's x, y, z (the Y sign flip and the
        Z, -Y, X field order are applied here).
    imu_type, imu_info, status : header fields (scalars or (n,) arrays).

    Returns
    -------
    bytes : n * 56 bytes.
    """
    sow = np.atleast_1d(np.asarray(sow_s, float))
    n = sow.shape[0]
    rec = np.zeros(n, dtype=FRAME_DTYPE)
    rec["sync"] = np.frombuffer(SYNC_SHORT, np.uint8)
    rec["body_len"] = BODY_LEN
    rec["msg_id"] = MSG_ID_RAWIMUSX
    wk = np.broadcast_to(np.asarray(week, np.int64), (n,))
    rec["hdr_week"] = wk
    rec["week"] = wk
    rec["hdr_ms"] = np.rint(sow * 1000.0).astype(np.int64)
    rec["sow"] = sow
    rec["imu_info"] = imu_info
    rec["imu_type"] = imu_type
    rec["status"] = status
    g = np.asarray(gyro_counts, np.int64)
    a = np.asarray(accel_counts, np.int64)
    rec["acc_z"], rec["acc_ny"], rec["acc_x"] = a[:, 2], -a[:, 1], a[:, 0]
    rec["gyr_z"], rec["gyr_ny"], rec["gyr_x"] = g[:, 2], -g[:, 1], g[:, 0]
    rows = rec.view(np.uint8).reshape(n, FRAME_LEN)
    rec["crc"] = crc32_rows(rows[:, : HEADER_LEN + BODY_LEN])
    return rec.tobytes()


# ----------------------------------------------------------------------------- vectorised parse
@dataclass
class BufferParse:
    """Result of parsing one byte buffer.

    Attributes
    ----------
    rows : accepted RAWIMUSX frames as a FRAME_DTYPE array.
    starts : byte offsets of those frames.
    span_starts, span_ends : offsets of every accepted frame (RAWIMUSX and other logs), sorted.
    bad_crc : sync candidates that were checked and failed the CRC (not inside a good frame).
    other_msgs : CRC-valid short-header frames that are not RAWIMUSX (other logs on the port).
    keep_from : offset of the first byte that may still start a frame (needs more bytes).
    bytes_ok : bytes inside accepted frames (all kinds).
    """

    rows: np.ndarray
    starts: np.ndarray
    span_starts: np.ndarray
    span_ends: np.ndarray
    bad_crc: int
    other_msgs: int
    keep_from: int
    bytes_ok: int


def _inside(x: np.ndarray, s: np.ndarray, e: np.ndarray, strict_start: bool = False) -> np.ndarray:
    """Which offsets x lie inside one of the sorted, disjoint spans [s, e)."""
    if s.size == 0 or x.size == 0:
        return np.zeros(x.shape, bool)
    k = np.searchsorted(s, x, side="left" if strict_start else "right") - 1
    return (k >= 0) & (x < e[np.maximum(k, 0)])


def parse_rawimusxb_buffer(buf: bytes | bytearray | memoryview | np.ndarray, final: bool = False) -> BufferParse:
    """Find and check every RAWIMUSXB frame in ``buf`` at once (numpy, no per-byte loop).

    Sync candidates come from three shifted comparisons of the whole buffer; the 52 header+body
    bytes of every candidate with body length 40 are gathered with a sliding-window view and
    CRC-checked column-wise. Candidates declaring another body length (other short-header logs
    on the same port, or a corrupted length byte) are checked one by one with their own length;
    valid ones are skipped as ``other_msgs``. A frame is accepted if its CRC holds and it does
    not overlap an earlier accepted frame; failed candidates inside accepted frames are payload.

    Parameters
    ----------
    buf : bytes to scan.
    final : no more bytes will come (a trailing partial frame is discarded, not kept).
    """
    b = np.frombuffer(buf, dtype=np.uint8) if not isinstance(buf, np.ndarray) else buf
    n = b.shape[0]
    empty_i = np.zeros(0, np.int64)
    if n < 3:
        return BufferParse(np.zeros(0, FRAME_DTYPE), empty_i, empty_i, empty_i, 0, 0,
                           n if final else _tail_keep(b, n), 0)
    cand = np.flatnonzero((b[:-2] == 0xAA) & (b[1:-1] == 0x44) & (b[2:] == 0x13)).astype(np.int64)
    has_len = cand + 4 <= n
    lens = np.full(cand.size, -1, np.int64)
    lens[has_len] = b[cand[has_len] + 3]
    total = HEADER_LEN + lens + CRC_LEN
    complete = has_len & (cand + total <= n)
    is40 = complete & (lens == BODY_LEN)
    # RAWIMUSX-sized candidates: vectorised CRC across all of them
    c40 = cand[is40]
    if c40.size:
        win = np.lib.stride_tricks.sliding_window_view(b, FRAME_LEN)[c40]
        ok40 = crc32_rows(win[:, : HEADER_LEN + BODY_LEN]) == np.ascontiguousarray(win[:, HEADER_LEN + BODY_LEN:]).view("<u4")[:, 0]
    else:
        win, ok40 = np.zeros((0, FRAME_LEN), np.uint8), np.zeros(0, bool)
    # other lengths: rare, checked one by one with their declared length
    co = cand[complete & ~is40]
    ok_o = np.array([crc32(b[p: p + HEADER_LEN + int(b[p + 3])].tobytes())
                     == int.from_bytes(b[p + HEADER_LEN + int(b[p + 3]): p + HEADER_LEN + int(b[p + 3]) + 4].tobytes(), "little")
                     for p in co.tolist()], bool) if co.size else np.zeros(0, bool)
    g_start = np.concatenate([c40[ok40], co[ok_o]])
    g_len = np.concatenate([np.full(int(ok40.sum()), FRAME_LEN, np.int64), (HEADER_LEN + CRC_LEN + b[co[ok_o] + 3]).astype(np.int64)])
    order = np.argsort(g_start, kind="stable")
    g_start, g_len = g_start[order], g_len[order]
    if g_start.size > 1:  # drop frames overlapping the previous one (a frame embedded in a frame)
        keep = np.ones(g_start.size, bool)
        keep[1:] = g_start[1:] >= g_start[:-1] + g_len[:-1]
        g_start, g_len = g_start[keep], g_len[keep]
    g_end = g_start + g_len
    # failed candidates, and pending ones that a later valid frame proves bogus
    bad = np.concatenate([c40[~ok40], co[~ok_o]])
    bad = bad[~_inside(bad, g_start, g_end)]
    pend = cand[~complete]
    pend = pend[~_inside(pend, g_start, g_end)]
    if g_start.size and pend.size:
        proven = pend < g_start[-1]
        bad = np.concatenate([bad, pend[proven]])
        pend = pend[~proven]
    # decode the accepted RAWIMUSX-sized frames
    if c40.size and g_start.size:  # both sorted: membership by binary search
        k = np.minimum(np.searchsorted(g_start, c40), g_start.size - 1)
        acc40 = g_start[k] == c40
    else:
        acc40 = np.zeros(c40.size, bool)
    rows = np.ascontiguousarray(win[acc40 & ok40]).view(FRAME_DTYPE)[:, 0] if (acc40 & ok40).any() else np.zeros(0, FRAME_DTYPE)
    starts40 = c40[acc40 & ok40]
    is_imu = (rows["msg_id"] == MSG_ID_RAWIMUSX) & (rows["body_len"] == BODY_LEN)
    other = int(g_start.size - is_imu.sum())
    end_good = int(g_end[-1]) if g_end.size else 0
    if final:  # what never completed is a lost frame too
        bad = np.concatenate([bad, pend])
        keep_from = n
    elif pend.size:
        keep_from = max(int(pend[0]), end_good)
    else:
        keep_from = max(end_good, _tail_keep(b, n))
    bad = bad[bad < keep_from]  # the rest is looked at again with the next read
    return BufferParse(rows[is_imu], starts40[is_imu], g_start, g_end, int(bad.size), other,
                       keep_from, int(g_len.sum()))


def _tail_keep(b: np.ndarray, n: int) -> int:
    """Offset of a trailing partial sync (AA or AA 44) that the next read may complete."""
    if n >= 2 and b[n - 2] == 0xAA and b[n - 1] == 0x44:
        return n - 2
    if n >= 1 and b[n - 1] == 0xAA:
        return n - 1
    return n


def rate_from_times(t_s) -> float:
    """Data rate (Hz) from time stamps: 1 / median of the positive steps (robust to gaps and
    repeats), snapped to whole hertz when within 1e-6 relative (IMU rates are whole hertz;
    the float seconds-of-week add ~1e-11 s noise to each step).

    Raises
    ------
    ValueError : fewer than two distinct time stamps.
    """
    d = np.diff(np.asarray(t_s, float))
    d = d[d > 0]
    if d.size == 0:
        raise ValueError("need at least two distinct time stamps to infer a data rate")
    r = 1.0 / float(np.median(d))
    return float(round(r)) if abs(r - round(r)) <= 1e-6 * r else r


class RawImuParser:
    """Streaming RAWIMUSXB parser: feed it reads, get decoded frames; keeps counters.

    Bytes of a frame split across reads are carried over. Garbage, frames with a bad CRC and
    dropped bytes are skipped by re-synchronising on the next sync candidate. Time-stamp gaps
    (seconds-of-week steps larger than 1.5 nominal periods) and frames with the IMU error bit
    are counted in ``stats.extra`` as ``time_gaps``, ``frames_missing`` and ``imu_error_frames``.

    Parameters
    ----------
    stats : counters to update (a :class:`drivers.stats.Stats`).
    rate_hz : nominal data rate. None: inferred (:func:`rate_from_times`) from the first
        ``infer_frames + 1`` frames, whose gaps are then counted too; until then :attr:`rate`
        is None. The rate in use is reported as ``stats.extra["rate_hz"]``.
    infer_frames : time steps used to infer the rate.
    """

    def __init__(self, stats, rate_hz: float | None = None, infer_frames: int = 20) -> None:
        self.stats = stats
        self.rate_hz = rate_hz
        self.infer_frames = infer_frames
        self.rate: float | None = float(rate_hz) if rate_hz else None
        self._head: list[np.ndarray] = []  # time stamps waiting for the rate inference
        self._buf = bytearray()
        self._discarding = False
        self._last_t: float | None = None
        self._ref: tuple[int, float] | None = None
        for k in ("time_gaps", "frames_missing", "imu_error_frames", "other_msgs"):
            stats.extra.setdefault(k, 0)
        if self.rate is not None:
            stats.extra["rate_hz"] = self.rate

    def feed(self, data: bytes, t_host: float) -> ImuFrames:
        """Parse ``data`` (one read, received at host time ``t_host``)."""
        st = self.stats
        st.bytes_in += len(data)
        self._buf += data
        return self._parse(t_host, final=False)

    def flush(self, t_host: float = float("nan")) -> ImuFrames:
        """No more data: discard what is left (counted) and return any last frames."""
        return self._parse(t_host, final=True)

    def _gaps(self, t: np.ndarray, final: bool) -> None:
        """Count time-stamp gaps of ``t`` (continuing the previous frames)."""
        if self.rate is None:
            self._head.append(t)
            head = np.concatenate(self._head)
            if head.size < self.infer_frames + 1 and not (final and head.size >= 3):
                return
            try:
                self.rate = rate_from_times(head)
            except ValueError:
                return
            self.stats.extra["rate_hz"] = self.rate
            self._head = []
            t = head
        st = self.stats
        prev = np.concatenate([[self._last_t if self._last_t is not None else t[0]], t[:-1]])
        dt = t - prev
        period = 1.0 / self.rate
        gap = dt > 1.5 * period
        st.extra["time_gaps"] += int(gap.sum())
        st.extra["frames_missing"] += int(np.rint(dt[gap] / period).sum() - gap.sum())
        self._last_t = float(t[-1])

    def _parse(self, t_host: float, final: bool) -> ImuFrames:
        st = self.stats
        res = parse_rawimusxb_buffer(bytes(self._buf), final=final)
        consumed = res.keep_from
        discarded = consumed - res.bytes_ok
        st.frames_ok += len(res.rows)
        st.bytes_ok += res.bytes_ok
        st.bytes_discarded += discarded
        st.bad_checksum += res.bad_crc
        st.extra["other_msgs"] += res.other_msgs
        # a resync is one run of skipped bytes; a run may continue across reads
        edges = np.concatenate([[0], res.span_ends])
        ends = np.concatenate([res.span_starts, [consumed]])
        runs = ends - edges > 0
        st.resyncs += int(runs.sum()) - int(bool(runs[0]) and self._discarding and edges[0] == 0)
        if res.span_starts.size == 0:
            self._discarding = self._discarding if consumed == 0 else bool(runs[-1])
        else:
            self._discarding = bool(runs[-1])
        del self._buf[:consumed]
        st.bytes_pending = len(self._buf)
        frames = _frames_from_rows(res.rows, np.full(len(res.rows), t_host))
        if len(frames):
            st.extra["imu_error_frames"] += int((frames.imu_info & IMU_INFO_ERROR_BIT).astype(bool).sum())
            if self._ref is None:
                self._ref = (int(frames.week[0]), float(frames.sow_s[0]))
            # relative to the first frame: absolute GPS seconds (~1.4e9) keep only ~2e-7 s
            self._gaps(frames.seconds_since(*self._ref), final)
        elif final and self._head:
            self._gaps(np.zeros(0), final)
        return frames


# ----------------------------------------------------------------------------- ASCII form
_XA_RE = re.compile(
    r"^%RAWIMUSXA,(\d+),([0-9.]+);([0-9a-fA-F]{1,2}),(\d+),(\d+),([0-9.]+),([0-9a-fA-F]{1,8}),"
    r"(-?\d+),(-?\d+),(-?\d+),(-?\d+),(-?\d+),(-?\d+)\*([0-9a-fA-F]{8})$"
)


class NovatelChecksumError(ValueError):
    """A NovAtel frame or line whose CRC-32 does not match."""


def format_rawimusxa(week: int, sow_s: float, gyro_counts, accel_counts, imu_type: int = 26,
                     imu_info: int = 0, status: int = 0) -> str:
    """One ``%RAWIMUSXA`` line (with CRLF) for one sample (counts about the IMU's x, y, z)."""
    g = [int(v) for v in gyro_counts]
    a = [int(v) for v in accel_counts]
    body = (f"{ASCII_NAME},{week},{sow_s:.3f};{imu_info:02x},{imu_type},{week},{sow_s:.6f},{status:08x},"
            f"{a[2]},{-a[1]},{a[0]},{g[2]},{-g[1]},{g[0]}")
    return f"%{body}*{crc32(body.encode('ascii')):08x}\r\n"


def parse_rawimusxa(line: str | bytes, t_host: float = float("nan")) -> ImuFrames:
    """Decode one ``%RAWIMUSXA`` line into a one-row :class:`ImuFrames`.

    Raises
    ------
    NovatelChecksumError : CRC-32 mismatch.
    ValueError : not a RAWIMUSXA line.
    """
    s = line.decode("ascii", "replace") if isinstance(line, (bytes, bytearray)) else line
    s = s.strip()
    m = _XA_RE.match(s)
    if not m:
        raise ValueError(f"not a %RAWIMUSXA line: {s[:60]!r}")
    crc = crc32(s[1: s.rindex("*")].encode("ascii"))
    if crc != int(m.group(14), 16):
        raise NovatelChecksumError(f"RAWIMUSXA CRC mismatch: computed {crc:08x}, line says {m.group(14)}")
    v = [int(m.group(i)) for i in range(8, 14)]
    return ImuFrames(np.array([t_host]), np.array([int(m.group(5))]), np.array([float(m.group(6))]),
                     np.array([int(m.group(3), 16)], np.uint8), np.array([int(m.group(4))], np.uint8),
                     np.array([int(m.group(7), 16)], np.uint32),
                     np.array([[v[5], -v[4], v[3]]], np.int64), np.array([[v[2], -v[1], v[0]]], np.int64))


def parse_rawimusxa_lines(text: str | bytes, stats=None) -> ImuFrames:
    """Decode every ``%RAWIMUSXA`` line of a text log; bad lines are skipped (and counted).

    Parameters
    ----------
    text : log text. Other NovAtel logs (``%RAWIMUSA``, ``#INSPVAA``, ...) are counted as
        ``stats.extra["other_msgs"]``, not decoded (RAWIMUSA has no IMU type field); lines that
        are no NovAtel log at all (comments, blank lines) are ignored.
    stats : optional :class:`drivers.stats.Stats`; ``frames_ok``, ``bad_checksum``,
        ``bad_format`` and ``extra["other_msgs"]`` are updated.
    """
    s = text.decode("ascii", "replace") if isinstance(text, (bytes, bytearray)) else text
    out = []
    other = 0
    for line in s.splitlines():
        j = line.rfind("%" + ASCII_NAME + ",")
        if j < 0:
            other += _OTHER_LOG_RE.search(line) is not None
            continue
        try:
            out.append(parse_rawimusxa(line[j:]))
            if stats is not None:
                stats.frames_ok += 1
        except NovatelChecksumError:
            if stats is not None:
                stats.bad_checksum += 1
        except ValueError:
            if stats is not None:
                stats.bad_format += 1
    if stats is not None:
        stats.extra["other_msgs"] = stats.extra.get("other_msgs", 0) + other
    return ImuFrames.concat(out)


#: the start of any NovAtel ASCII log: long header ``#NAMEA,`` or short header ``%NAMEA,``
_OTHER_LOG_RE = re.compile(r"[#%][A-Z][A-Z0-9]*A,")
