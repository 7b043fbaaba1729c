"""Quadrature-encoder counter module (odometer): BEI-style ASCII protocol, polling, distance.

Protocol (protocols.md section 5, BEI Sensors dual encoder-to-USB module), 115200 8N1:

    $0R0<CR>                        read both channels
    *0R0<count1>,<count2><CR>       counts, unsigned, zero-padded to the counter width
    *0ACK<CR> / *0NACK<CR>          other commands: success / failure

Field width is 3, 5, 8 or 10 digits for 8, 16, 24 or 32-bit counters. The protocol has no
checksum: the driver checks the exact format, the value range and a speed plausibility gate,
but a digit changed into another digit in the low places cannot be detected (docs/drivers.md).

Distance: ``d_count = pi * D / (PPR * k)``, ``s = SF * sum(delta counts) * d_count`` with
``delta = ((c1 - c0 + 2^(n-1)) mod 2^n) - 2^(n-1)`` (signed modular difference, rollover safe).

Speed gate and anchoring: a reading is accepted when it is within ``max_speed_m_s`` of the last
accepted one (the anchor). At the start and after every reconnect there is no anchor: readings
are withheld until ``confirm`` consecutive ones agree with each other, so a corrupt first reply
cannot become the anchor. With an anchor, ``confirm`` consecutive readings that agree with each
other but not with the anchor (the counter was reset, or the anchor was wrong) re-anchor the
gate instead of locking the odometer out. A new anchor that does not continue the old one
starts a new *segment*: the count difference across segments is not distance travelled.
"""
from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass

import numpy as np

from drivers.lineparser import LineParser, Unconfirmed
from drivers.stats import Stats

ADDRESS = 0
READ_COMMAND = b"$0R0\r"
READ_PREFIX = "*0R0"
REPLY_START = b"*0"
TERMINATOR = b"\r"
ACK = "*0ACK"
NACK = "*0NACK"
FIELD_WIDTH = {8: 3, 16: 5, 24: 8, 32: 10}
#: counter width (bits) told by the digits of a reply's count fields
WIDTH_BITS = {w: b for b, w in FIELD_WIDTH.items()}
_ANY_READ_RE = re.compile(r"^\*0R0(\d+),(\d+)$")


class CounterWidthMismatch(ValueError):
    """The counter's replies tell another counter width than the one configured."""


def width_mismatch_error(stats: Stats, cfg: "OdometerConfig", port: str = "") -> CounterWidthMismatch | None:
    """The error to raise after a recording whose replies had another field width, or None.

    The field width tells the counter width unambiguously (3, 5, 8, 10 digits for 8, 16, 24,
    32 bits), so the message names the ``--odometer-bits`` value to record with.
    """
    n = int(stats.extra.get("width_mismatch", 0))
    if not n:
        return None
    seen = int(stats.extra.get("counter_bits_seen", 0))
    where = f"odometer on {port}" if port else "odometer"
    return CounterWidthMismatch(
        f"{where}: {n} counter replies have {FIELD_WIDTH[seen]}-digit counts, the field width of a "
        f"{seen}-bit counter, but the odometer is set to {cfg.bits} bits ({FIELD_WIDTH[cfg.bits]} digits); "
        f"those replies were refused. Record again with --odometer-bits {seen} "
        f"(\"odometer_config\": {{\"bits\": {seen}}} in a field session's devices file)")
DEFAULT_BAUD = 115200


@dataclass(frozen=True)
class OdometerConfig:
    """Odometer wheel and counter settings.

    Attributes
    ----------
    ppr : encoder pulses per revolution.
    decode : quadrature decode multiplier (1, 2 or 4).
    wheel_diameter_m : measuring-wheel diameter.
    scale : calibrated scale factor SF (dimensionless, nominally 1).
    bits : counter width (8, 16, 24, 32).
    channel : which counter channel the odometer is on (1 or 2).
    rate_hz : polling rate.
    max_speed_m_s : readings implying a faster speed are rejected as corrupt.
    confirm : consecutive mutually consistent readings needed to (re-)anchor the speed gate.
    """

    ppr: int = 1024
    decode: int = 4
    wheel_diameter_m: float = 0.1
    scale: float = 1.0
    bits: int = 32
    channel: int = 1
    rate_hz: float = 100.0
    max_speed_m_s: float = 10.0
    confirm: int = 3

    def __post_init__(self) -> None:
        if self.decode not in (1, 2, 4):
            raise ValueError(f"odometer decode multiplier must be 1, 2 or 4, not {self.decode}")
        if self.bits not in FIELD_WIDTH:
            raise ValueError(f"counter width must be one of {sorted(FIELD_WIDTH)} bits, not {self.bits}")
        if self.ppr <= 0 or self.wheel_diameter_m <= 0 or self.rate_hz <= 0:
            raise ValueError("odometer ppr, wheel diameter and rate must be positive")
        if self.confirm < 2:
            raise ValueError(f"odometer confirm must be at least 2 readings, not {self.confirm}")

    @property
    def metres_per_count(self) -> float:
        """Distance of one count, scale factor included."""
        return self.scale * np.pi * self.wheel_diameter_m / (self.ppr * self.decode)


@dataclass(frozen=True)
class EncoderRecord:
    """One counter read: host time of the reply, both channels' raw counts, and the segment
    (incremented when the gate re-anchored on readings that do not continue the previous ones,
    e.g. after a counter reset)."""

    t_host_s: float
    count1: int
    count2: int
    segment: int = 0


def format_read_reply(count1: int, count2: int, bits: int = 32) -> bytes:
    """``*0R0<c1>,<c2>\\r`` with the counts wrapped to ``bits`` and zero-padded."""
    w = FIELD_WIDTH[bits]
    m = 2**bits
    return f"{READ_PREFIX}{count1 % m:0{w}d},{count2 % m:0{w}d}\r".encode("ascii")


def signed_delta(c1, c0, bits: int):
    """Signed modular difference ``c1 - c0`` of ``bits``-bit counters (arrays or ints)."""
    m = 2**bits
    h = 2 ** (bits - 1)
    return ((np.asarray(c1, np.int64) - np.asarray(c0, np.int64) + h) % m) - h


def unwrap_counts(counts, bits: int, segment=None) -> np.ndarray:
    """Cumulative signed counts from raw wrapped readings (first reading = 0).

    ``segment`` (per reading, :attr:`EncoderRecord.segment`): the step into a new segment is
    not counted (the distance carries on from the last reading of the previous segment).
    """
    c = np.asarray(counts, np.int64)
    if c.size == 0:
        return c
    d = signed_delta(c[1:], c[:-1], bits)
    if segment is not None:
        d = np.where(np.diff(np.asarray(segment)) != 0, 0, d)
    return np.concatenate([[0], np.cumsum(d)])


def distance_m(counts, cfg: OdometerConfig, segment=None) -> np.ndarray:
    """Cumulative distance (m) from raw wrapped counter readings (see :func:`unwrap_counts`)."""
    return unwrap_counts(counts, cfg.bits, segment) * cfg.metres_per_count


class EncoderParser(LineParser):
    """Streaming parser for counter replies, with format, range and speed checks.

    Implausible readings (a jump faster than ``max_speed_m_s`` from the anchor) are rejected and
    counted in ``stats.extra['implausible']`` (and in ``bad_format``); readings withheld while
    there is no anchor in ``extra['unconfirmed']`` (their bytes are discarded); re-anchorings in
    ``extra['reanchors']``, new segments after a reconnect in ``extra['counter_resets']``; NACKs
    in ``extra['nack']``. The parser notices a reconnect from ``stats.reconnects``.
    """

    def __init__(self, stats: Stats, cfg: OdometerConfig = OdometerConfig()) -> None:
        super().__init__(stats, self._decode, REPLY_START, TERMINATOR, max_line=64)
        self.cfg = cfg
        w = FIELD_WIDTH[cfg.bits]
        self._re = re.compile(rf"^\*0R0(\d{{{w}}}),(\d{{{w}}})$")
        self._anchor: tuple[float, int] | None = None
        self._before: tuple[float, int] | None = None  # last anchor before a reconnect
        self._chain: list[tuple[float, int]] = []  # consecutive readings agreeing with each other
        self._reconnects = stats.reconnects
        self.segment = 0
        for k in ("implausible", "nack", "ack", "unconfirmed", "reanchors", "counter_resets"):
            stats.extra.setdefault(k, 0)

    def _consistent(self, a: tuple[float, int], b: tuple[float, int]) -> bool:
        """Whether reading b can follow reading a without exceeding ``max_speed_m_s``."""
        (t0, c0), (t1, c1) = a, b
        dt = max(t1 - t0, 0.0) if t1 == t1 and t0 == t0 else 0.0
        # allow one missed poll of slack on top of the elapsed time
        limit = self.cfg.max_speed_m_s * (dt + 2.0 / self.cfg.rate_hz) / self.cfg.metres_per_count
        return abs(int(signed_delta(c1, c0, self.cfg.bits))) <= limit

    def _extend_chain(self, r: tuple[float, int]) -> bool:
        """Add r to the chain of agreeing readings (or start a new one); True when confirmed."""
        if self._chain and self._consistent(self._chain[-1], r):
            self._chain.append(r)
        else:
            self._chain = [r]
        return len(self._chain) >= self.cfg.confirm

    def _decode(self, text: str, t_host: float):
        if text == ACK:
            self.stats.extra["ack"] += 1
            return None
        if text == NACK:
            self.stats.extra["nack"] += 1
            return None
        m = self._re.match(text)
        if not m:
            g = _ANY_READ_RE.match(text)
            if g and len(g.group(1)) == len(g.group(2)) and len(g.group(1)) in WIDTH_BITS:
                # a well-formed reply of another counter width: its counts would wrap at the
                # wrong modulus, so it is refused and counted (width_mismatch_error says what to do)
                self.stats.extra["width_mismatch"] = self.stats.extra.get("width_mismatch", 0) + 1
                self.stats.extra["counter_bits_seen"] = WIDTH_BITS[len(g.group(1))]
                raise ValueError(f"counter reply {text!r} is of a {WIDTH_BITS[len(g.group(1))]}-bit counter, "
                                 f"not {self.cfg.bits}-bit (--odometer-bits)")
            raise ValueError(f"not a counter reply: {text[:40]!r}")
        c1, c2 = int(m.group(1)), int(m.group(2))
        if c1 >= 2**self.cfg.bits or c2 >= 2**self.cfg.bits:
            raise ValueError(f"count out of range in {text!r}")
        r = (t_host, c1 if self.cfg.channel == 1 else c2)
        ex = self.stats.extra
        if self.stats.reconnects != self._reconnects:  # the module may have been power-cycled
            self._reconnects = self.stats.reconnects
            if self._anchor is not None:
                self._before = self._anchor
            self._anchor, self._chain = None, []
        if self._anchor is not None:
            if self._consistent(self._anchor, r):
                self._chain = []
            elif self._extend_chain(r):
                ex["reanchors"] += 1
                self.segment += 1
                self._chain = []
            else:
                ex["implausible"] += 1
                raise ValueError(f"implausible counter jump in {text!r}")
        else:
            if not self._extend_chain(r):
                raise Unconfirmed(text)
            first = self._chain[0]
            if self._before is not None and not self._consistent(self._before, first):
                ex["counter_resets"] += 1
                self.segment += 1
            self._before, self._chain = None, []
        self._anchor = r
        return EncoderRecord(t_host, c1, c2, self.segment)


class OdometerPoller:
    """Polls the counter module at ``cfg.rate_hz`` over a :class:`drivers.serialport.SerialLink`.

    One request at a time: the next poll is sent on schedule but never before the previous
    one was answered (any complete reply line, good or bad) or given up. A poll with no reply
    within ``reply_timeout_s`` is counted in ``stats.timeouts``; the poller then still listens
    for its late reply for up to ``late_window_s`` before the next poll, so that a busy module's
    late reply is never taken for the answer to the next poll (which would leave every later
    reply attributed one poll late, and a later unanswered poll uncounted).
    """

    def __init__(self, link, cfg: OdometerConfig, reply_timeout_s: float | None = None,
                 late_window_s: float | None = None) -> None:
        self.link = link
        self.cfg = cfg
        self.reply_timeout_s = reply_timeout_s if reply_timeout_s is not None else max(0.05, 5.0 / cfg.rate_hz)
        self.late_window_s = late_window_s if late_window_s is not None else 2.0 * self.reply_timeout_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.polls = 0

    def start(self) -> "OdometerPoller":
        """Start the polling thread."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="odometer-poll", daemon=True)
        self._thread.start()
        return self

    def _lines(self) -> int:
        st = self.link.stats  # every complete reply line, withheld ones included
        return st.frames_ok + st.bad_checksum + st.bad_format + int(st.extra.get("unconfirmed", 0))

    def _run(self) -> None:
        period = 1.0 / self.cfg.rate_hz
        nxt = time.monotonic()
        link = self.link
        while not self._stop.is_set():
            with link.lock:
                before = self._lines()
            try:
                link.write(READ_COMMAND)
                self.polls += 1
                with link.fed:
                    if not link.fed.wait_for(lambda: self._lines() > before, self.reply_timeout_s):
                        link.stats.timeouts += 1
                        # late or lost: a late reply still belongs to this poll
                        link.fed.wait_for(lambda: self._lines() > before, self.late_window_s)
            except Exception:  # port gone: the link reconnects; keep the schedule
                self._stop.wait(period)
            nxt += period
            delay = nxt - time.monotonic()
            if delay < -period:  # fell behind (loaded machine): do not burst to catch up
                nxt = time.monotonic()
                delay = 0.0
            self._stop.wait(max(delay, 0.0))

    def stop(self) -> None:
        """Stop polling."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
