"""Gauge sensor (displacement transducer) line protocol and driver; see docs/gauge_protocol.md.

    $GG,<seq>,<t_ms>,<gauge_mm>,<status>*<CRC16>\\r\\n

``seq`` counts lines modulo 65536, ``t_ms`` is the sensor's own millisecond clock modulo 2^32,
``gauge_mm`` is the full track gauge in millimetres with two decimals, ``status`` 0 = OK,
1 = out of range, 2 = sensor fault. CRC16 is CRC-16/ARC (the GeoCOM checksum) over the
characters between ``$`` and ``*`` (exclusive), as four upper-case hex digits.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from drivers.geocom import crc16
from drivers.lineparser import ChecksumError, LineParser
from drivers.stats import Stats
from trolley import units

START = b"$GG,"
TERMINATOR = b"\r\n"
SEQ_MODULO = 65536
MS_MODULO = 2**32
STATUS_OK, STATUS_OUT_OF_RANGE, STATUS_SENSOR_FAULT = 0, 1, 2
DEFAULT_BAUD = 115200
_LINE_RE = re.compile(r"^\$(GG,(\d{1,5}),(\d{1,10}),(-?\d+\.\d{2}),([0-2]))\*([0-9A-F]{4})$")


@dataclass(frozen=True)
class GaugeRecord:
    """One gauge reading: host time, sensor sequence and clock, gauge (m), status."""

    t_host_s: float
    seq: int
    t_device_ms: int
    gauge_m: float
    status: int


def format_line(seq: int, t_ms: int, gauge_m: float, status: int = STATUS_OK) -> bytes:
    """One protocol line for gauge ``gauge_m`` (metres)."""
    body = f"GG,{seq % SEQ_MODULO},{t_ms % MS_MODULO},{units.m_to_mm(gauge_m):.2f},{status}"
    return f"${body}*{crc16(body):04X}\r\n".encode("ascii")


def decode_line(text: str, t_host: float = float("nan")) -> GaugeRecord:
    """Decode one line (without terminator).

    Raises
    ------
    ChecksumError : CRC mismatch.
    ValueError : not a gauge line.
    """
    m = _LINE_RE.match(text)
    if not m:
        raise ValueError(f"not a gauge line: {text[:60]!r}")
    if crc16(m.group(1)) != int(m.group(6), 16):
        raise ChecksumError(f"gauge CRC mismatch in {text[:60]!r}")
    return GaugeRecord(t_host, int(m.group(2)), int(m.group(3)), units.mm_to_m(float(m.group(4))), int(m.group(5)))


class GaugeParser(LineParser):
    """Streaming gauge parser; counts sequence gaps (``seq_gaps``, ``lines_missing``)."""

    def __init__(self, stats: Stats) -> None:
        super().__init__(stats, self._decode, START, b"\n", max_line=128)
        self._last_seq: int | None = None
        for k in ("seq_gaps", "lines_missing", "status_not_ok"):
            stats.extra.setdefault(k, 0)

    def _decode(self, text: str, t_host: float) -> GaugeRecord:
        rec = decode_line(text, t_host)
        if self._last_seq is not None:
            step = (rec.seq - self._last_seq) % SEQ_MODULO
            if step != 1:
                self.stats.extra["seq_gaps"] += 1
                self.stats.extra["lines_missing"] += (step - 1) % SEQ_MODULO
        self._last_seq = rec.seq
        if rec.status != STATUS_OK:
            self.stats.extra["status_not_ok"] += 1
        return rec


def gauge_arrays(records: list[GaugeRecord], only_ok: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(t_host_s, gauge_m) arrays of the records (only status OK ones by default)."""
    recs = [r for r in records if r.status == STATUS_OK] if only_ok else list(records)
    return (np.array([r.t_host_s for r in recs], float), np.array([r.gauge_m for r in recs], float))
