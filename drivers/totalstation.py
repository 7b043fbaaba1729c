"""GeoCOM total-station client: one request at a time, transaction ids, CRC, bounded retries.

The survey calls (protocols.md section 1.5/1.6): COM_NullProc, COM_GetSWVersion, AUT_FineAdjust,
TMC_DoMeasure, TMC_GetSimpleMea, TMC_GetCoordinate, TMC_GetAngle, BAP_MeasDistanceAngle,
TMC_SetStation / GetStation / SetOrientation / SetHeight and AUT_MakePositioning (what a
free-station setup on CPIII points needs), and TMC_SetPrismCorr / TMC_GetPrismCorr (the prism
constant, switched between the CPIII prisms and the trolley prism and always read back). Transient failures (timeouts, no target, ATR not
locked, busy, checksum) are retried with exponential back-off, bounded in count and time;
everything else raises the typed :class:`drivers.geocom.GeoComError` at once.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from drivers import geocom as gc
from drivers.lineparser import ChecksumError, LineParser
from drivers.serialport import DeviceError, SerialLink
from drivers.stats import Stats
from trolley import units

DEFAULT_BAUD = 19200
#: largest difference between the prism constant asked for and the one read back, m: GeoCOM sends
#: doubles with enough digits to read back exactly (COM_GetDoublePrecision), so anything beyond
#: rounding means the instrument holds another constant
PRISM_CONSTANT_TOLERANCE_M = 0.05e-3
#: return codes of a TMC_SetPrismCorr the instrument cannot carry out (unknown RPC on this firmware,
#: not implemented): the constant may still be right, set on the instrument's keyboard; the
#: read-back decides. One GeoCOM client (JGeoCOM, applied-geodesy.org) marks TMC_SetPrismCorr as
#: dropped from GeoCOM 1.5 on; TMC_GetPrismCorr is in every reference we have (protocols.md 1.5).
PRISM_SET_UNAVAILABLE = frozenset({5, 3081})


@dataclass(frozen=True)
class RetryPolicy:
    """Bounded exponential back-off.

    Attributes
    ----------
    attempts : total tries per call (1 = no retry).
    base_delay_s, max_delay_s : delay before retry k is ``min(base * 2**k, max)``.
    total_s : give up when this much time has passed since the first try.
    """

    attempts: int = 5
    base_delay_s: float = 0.05
    max_delay_s: float = 2.0
    total_s: float = 60.0


@dataclass(frozen=True)
class Measurement:
    """One prism measurement: angles, slope distance, grid coordinates, return code, host time,
    and the instrument's own time stamp of the coordinates (TMC_GetCoordinate ``CoordTime``,
    ms on the instrument's clock, whose epoch the manuals do not state; protocols.md 1.3)."""

    hz_rad: float
    v_rad: float
    slope_m: float
    E_m: float
    N_m: float
    H_m: float
    rc: int
    t_host_s: float
    coord_time_ms: int | None = None


@dataclass(frozen=True)
class BadReply:
    """A reply line that was rejected (``kind`` "checksum" or "format"); lets a waiting call
    retry at once instead of waiting for its timeout."""

    kind: str
    t_host_s: float


class PrismConstantError(RuntimeError):
    """The instrument holds another prism constant than the one asked for (read back after
    TMC_SetPrismCorr).

    Attributes
    ----------
    device : the instrument's port.
    expected_m, read_m : the constant asked for and the one read back, m (Leica's convention).
    set_error : the GeoCOM error of a TMC_SetPrismCorr the instrument refused, or None.
    """

    def __init__(self, device: str, expected_m: float, read_m: float,
                 set_error: gc.GeoComError | None = None) -> None:
        self.device = device
        self.expected_m = float(expected_m)
        self.read_m = float(read_m)
        self.set_error = set_error
        why = (f"TMC_SetPrismCorr was refused ({set_error})" if set_error is not None
               else "read back after TMC_SetPrismCorr")
        # two decimals: a difference just over the 0.05 mm tolerance must show in the message
        super().__init__(f"total station {device}: prism constant {units.m_to_mm(self.read_m):+.2f} mm on the "
                         f"instrument, {units.m_to_mm(self.expected_m):+.2f} mm expected ({why})")


class GeoComReplyParser(LineParser):
    """Line parser producing :class:`drivers.geocom.Reply` records (and :class:`BadReply`)."""

    def on_bad(self, kind: str, text: str, t_host: float, out: list) -> None:
        out.append(BadReply(kind, t_host))

    def __init__(self, stats: Stats) -> None:
        super().__init__(stats, self._decode, gc.REPLY_START.encode(), b"\n", max_line=1024)

    @staticmethod
    def _decode(text: str, t_host: float) -> gc.Reply:
        try:
            return gc.decode_reply(text, t_host)
        except gc.GeoComChecksumError as e:
            raise ChecksumError(str(e)) from None
        except gc.GeoComProtocolError as e:
            raise ValueError(str(e)) from None


class TotalStation:
    """A Leica total station over GeoCOM ASCII.

    Parameters
    ----------
    port : serial port path.
    baudrate : 9600 and 19200 are both common in the field (must match the instrument).
    use_crc : add the CRC-16 field to requests (the instrument then answers with one, which is
        verified). Replies with a CRC field are always verified.
    timeout_s : reply timeout of quick calls; ``long_timeout_s`` for ATR / EDM calls.
    retry : retry policy for transient failures.
    raw_log : path of the raw byte log.
    """

    LONG_RPCS = frozenset({gc.AUT_FINEADJUST, gc.AUT_MAKEPOSITIONING, gc.BAP_MEASDISTANCEANGLE,
                           gc.TMC_GETCOORDINATE, gc.TMC_GETSIMPLEMEA, gc.AUT_LOCKIN})

    def __init__(self, port: str, baudrate: int = DEFAULT_BAUD, use_crc: bool = False,
                 timeout_s: float = 3.0, long_timeout_s: float = 15.0,
                 retry: RetryPolicy = RetryPolicy(), raw_log: str | Path | None = None,
                 reconnect: bool = True) -> None:
        self.stats = Stats()
        for k in ("retries", "stale_replies"):
            self.stats.extra[k] = 0
        self.link = SerialLink(port, GeoComReplyParser(self.stats), name="totalstation",
                               baudrate=baudrate, raw_log=raw_log, reconnect=reconnect)
        self.use_crc = use_crc
        self.timeout_s = timeout_s
        self.long_timeout_s = long_timeout_s
        self.retry = retry
        self._trid = 0
        #: the prism constant last set and read back (m); None: not verified since connecting
        self.verified_prism_constant_m: float | None = None
        #: the link's reconnect count when it was verified
        self._verified_reconnects = 0

    # ------------------------------------------------------------------ link
    def connect(self, open_timeout_s: float = 5.0) -> "TotalStation":
        """Open the port, clear the instrument's buffer with a LF and check with COM_NullProc."""
        self.link.start(open_timeout_s)
        self.link.write(gc.CLEAR_BUFFER)
        self.forget_prism_constant()
        self.null_proc()
        return self

    def detect_crc(self, attempts: int = 2) -> bool:
        """Switch the CRC-16 field on if the instrument answers a CRC-checked COM_NullProc with
        a valid CRC (GeoCOM makes the field optional; whether every model supports it is not
        documented, protocols.md 1.2); otherwise leave it off. Returns whether it is on."""
        self.use_crc = True
        for _ in range(attempts):
            try:
                self.call_once(gc.COM_NULLPROC)
                return True
            except gc.GeoComError:
                try:
                    self.link.write(gc.CLEAR_BUFFER)
                except DeviceError:
                    break
        self.use_crc = False
        return False

    def close(self) -> None:
        """Close the port and the raw log."""
        self.link.stop()

    def __enter__(self) -> "TotalStation":
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()

    def _next_trid(self) -> int:
        self._trid = self._trid + 1 if self._trid < gc.MAX_TRID else 1
        return self._trid

    # ------------------------------------------------------------------ calls
    def call_once(self, rpc: int, params: tuple = (), timeout_s: float | None = None,
                  ok: frozenset = frozenset({0})) -> gc.Reply:
        """Send one request and wait for its reply (no retry).

        Raises
        ------
        GeoComError subclass : the reply's RC (or RC_COM) is not in ``ok``; GeoComTimeout (3077)
            when no reply with this transaction id arrived in time.
        """
        if timeout_s is None:
            timeout_s = self.long_timeout_s if rpc in self.LONG_RPCS else self.timeout_s
        for stale in self.link.drain():
            if not isinstance(stale, BadReply):
                with self.link.lock:
                    self.stats.extra["stale_replies"] += 1
        trid = self._next_trid()
        try:
            self.link.write(gc.encode_request(rpc, params, trid, self.use_crc))
        except DeviceError as e:
            raise gc.GeoComError(3075, rpc, str(e)) from None
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            rep = self.link.get(max(left, 0.0)) if left > 0 else None
            if rep is None:
                with self.link.lock:
                    self.stats.timeouts += 1
                raise gc.GeoComTimeout(3077, rpc, f"no reply within {timeout_s:g} s")
            if isinstance(rep, BadReply):
                code = 3102 if rep.kind == "checksum" else 3078
                raise gc.error_for(code, rpc, "reply rejected")
            if self.use_crc and not rep.crc_present:
                raise gc.error_for(3110, rpc, "reply without the CRC field that was asked for")
            # a reply without the transaction-id field cannot be matched: taken as this one's
            if rep.trid is not None and rep.trid != trid:
                with self.link.lock:
                    self.stats.extra["stale_replies"] += 1
                continue
            if rep.com_rc != 0:
                raise gc.error_for(rep.com_rc, rpc)
            if rep.rc not in ok:
                raise gc.error_for(rep.rc, rpc)
            return rep

    def call(self, rpc: int, params: tuple = (), timeout_s: float | None = None,
             ok: frozenset = frozenset({0})) -> gc.Reply:
        """:meth:`call_once` with bounded exponential back-off on transient failures."""
        t0 = time.monotonic()
        for k in range(self.retry.attempts):
            try:
                return self.call_once(rpc, params, timeout_s, ok)
            except gc.GeoComError as e:
                last = k == self.retry.attempts - 1
                if not e.retryable or last or time.monotonic() - t0 > self.retry.total_s:
                    raise
                with self.link.lock:
                    self.stats.extra["retries"] += 1
                time.sleep(min(self.retry.base_delay_s * 2**k, self.retry.max_delay_s))
                try:  # clear a half-received request in the instrument
                    self.link.write(gc.CLEAR_BUFFER)
                except DeviceError:
                    pass
        raise AssertionError("unreachable")

    # ------------------------------------------------------------------ RPCs
    def null_proc(self) -> None:
        """COM_NullProc: connection check."""
        self.call(gc.COM_NULLPROC)

    def sw_version(self) -> tuple[int, int, int]:
        """COM_GetSWVersion: GeoCOM release, version, subversion."""
        p = self.call(gc.COM_GETSWVERSION).params
        return int(p[0]), int(p[1]), int(p[2])

    def fine_adjust(self, hz_window_rad: float = 0.0873, v_window_rad: float = 0.0873) -> None:
        """AUT_FineAdjust: ATR fine pointing on the prism inside the search window."""
        self.call(gc.AUT_FINEADJUST, (float(hz_window_rad), float(v_window_rad), 0))

    def make_positioning(self, hz_rad: float, v_rad: float, precise: bool = False, atr: bool = True) -> None:
        """AUT_MakePositioning: turn the telescope to (Hz, V); ATR target mode by default."""
        self.call(gc.AUT_MAKEPOSITIONING, (float(hz_rad), float(v_rad), int(precise), int(atr), 0))

    def do_measure(self, command: int = gc.TMC_DEF_DIST, mode: int = gc.TMC_AUTO_INC) -> None:
        """TMC_DoMeasure (1 = single distance, 3 = clear, 8 = rapid tracking, 0 = stop)."""
        self.call(gc.TMC_DOMEASURE, (int(command), int(mode)))

    def simple_mea(self, wait_ms: int = 3000, mode: int = gc.TMC_AUTO_INC) -> tuple[float, float, float, int]:
        """TMC_GetSimpleMea: (Hz, V, slope distance, rc); warnings 1283/1284 accepted."""
        r = self.call(gc.TMC_GETSIMPLEMEA, (int(wait_ms), int(mode)), ok=gc.TMC_RESULT_USABLE)
        return float(r.params[0]), float(r.params[1]), float(r.params[2]), r.rc

    def coordinate(self, wait_ms: int = 3000, mode: int = gc.TMC_AUTO_INC) -> tuple[float, float, float, int]:
        """TMC_GetCoordinate: (E, N, H, rc) of the static measurement."""
        return self._coordinate(wait_ms, mode)[:4]

    def _coordinate(self, wait_ms: int, mode: int) -> tuple[float, float, float, int, int | None]:
        """TMC_GetCoordinate: (E, N, H, rc, CoordTime ms or None when not in the reply)."""
        r = self.call(gc.TMC_GETCOORDINATE, (int(wait_ms), int(mode)), ok=gc.TMC_RESULT_USABLE)
        p = r.params
        t_ms = int(p[3]) if len(p) > 3 and isinstance(p[3], int) else None
        return float(p[0]), float(p[1]), float(p[2]), r.rc, t_ms

    def angle(self, mode: int = gc.TMC_AUTO_INC) -> tuple[float, float]:
        """TMC_GetAngle (GetAngle1): (Hz, V)."""
        r = self.call(gc.TMC_GETANGLE, (int(mode),), ok=gc.TMC_RESULT_USABLE)
        return float(r.params[0]), float(r.params[1])

    def meas_distance_angle(self, dist_mode: int = gc.BAP_DEF_DIST) -> tuple[float, float, float]:
        """BAP_MeasDistanceAngle: (Hz, V, slope distance) with the current ATR settings."""
        r = self.call(gc.BAP_MEASDISTANCEANGLE, (int(dist_mode),), ok=gc.TMC_RESULT_USABLE)
        return float(r.params[0]), float(r.params[1]), float(r.params[2])

    def set_station(self, e_m: float, n_m: float, h_m: float, instrument_height_m: float) -> None:
        """Clear the distance (TMC_DoMeasure CLEAR), then TMC_SetStation."""
        self.do_measure(gc.TMC_CLEAR)
        self.call(gc.TMC_SETSTATION, (float(e_m), float(n_m), float(h_m), float(instrument_height_m)))

    def station(self) -> tuple[float, float, float, float]:
        """TMC_GetStation: (E0, N0, H0, instrument height)."""
        p = self.call(gc.TMC_GETSTATION).params
        return float(p[0]), float(p[1]), float(p[2]), float(p[3])

    def set_orientation(self, hz_rad: float) -> None:
        """Clear the distance, then TMC_SetOrientation: the current direction reads ``hz_rad``."""
        self.do_measure(gc.TMC_CLEAR)
        self.call(gc.TMC_SETORIENTATION, (float(hz_rad),))

    def set_reflector_height(self, height_m: float) -> None:
        """TMC_SetHeight: reflector height above the measured point."""
        self.call(gc.TMC_SETHEIGHT, (float(height_m),))

    def set_prism_constant(self, constant_m: float) -> None:
        """TMC_SetPrismCorr: the additive constant (m, Leica's convention: relative to the round
        prism, 360° +0.0231) the instrument adds to every distance it measures from now on."""
        self.verified_prism_constant_m = None
        self.call(gc.TMC_SETPRISMCORR, (float(constant_m),))

    def forget_prism_constant(self) -> None:
        """Take the prism constant as not verified: the next :meth:`ensure_prism_constant` sets it
        and reads it back. For when another instrument may answer now, or this one may have
        restarted (a connect, the port back after it vanished, the instrument answering again
        after a fault: a battery changed)."""
        self.verified_prism_constant_m = None

    def prism_constant(self) -> float:
        """TMC_GetPrismCorr: the prism constant the instrument applies now, m."""
        return float(self.call(gc.TMC_GETPRISMCORR).params[0])

    def ensure_prism_constant(self, constant_m: float) -> float:
        """Make the instrument apply ``constant_m`` (m) and prove it by reading it back.

        Nothing is sent when this client set and read back the same constant last (a serial
        round trip saved per measurement); the first call after :meth:`connect`, after the port
        came back from a reconnect, or after :meth:`forget_prism_constant` always sets and reads
        back. A TMC_SetPrismCorr the firmware does not offer (:data:`PRISM_SET_UNAVAILABLE`)
        is not an error by itself: the read-back decides.

        Returns
        -------
        float : the constant read back, m.

        Raises
        ------
        PrismConstantError : the read-back differs by more than :data:`PRISM_CONSTANT_TOLERANCE_M`.
        GeoComError subclass : a call failed after its retries.
        """
        constant_m = float(constant_m)
        if self.link.stats.reconnects != self._verified_reconnects:
            self.forget_prism_constant()  # the port vanished and came back since it was verified
        known = self.verified_prism_constant_m
        if known is not None and abs(known - constant_m) <= PRISM_CONSTANT_TOLERANCE_M:
            return known
        refused = None
        try:
            self.set_prism_constant(constant_m)
        except gc.GeoComError as e:
            if e.code not in PRISM_SET_UNAVAILABLE:
                raise
            refused = e
        read = self.prism_constant()
        if abs(read - constant_m) > PRISM_CONSTANT_TOLERANCE_M:
            raise PrismConstantError(self.link.port, constant_m, read, refused)
        self.verified_prism_constant_m = read
        self._verified_reconnects = self.link.stats.reconnects
        return read

    def measure(self, wait_ms: int = 3000) -> Measurement:
        """One static prism measurement: DoMeasure(single), GetSimpleMea, GetCoordinate."""
        self.do_measure(gc.TMC_DEF_DIST)
        hz, v, sd, rc1 = self.simple_mea(wait_ms)
        e, n, h, rc2, t_ms = self._coordinate(wait_ms, gc.TMC_AUTO_INC)
        return Measurement(hz, v, sd, e, n, h, max(rc1, rc2), time.monotonic(), t_ms)
