"""Replay a raw byte log through the same parser the live link used.

Because the raw log keeps every chunk read with its host time, feeding the chunks back through
a fresh parser gives records identical to the live session (same frames, same host times) and
the same counters (except ``bytes_out`` and ``timeouts``, which belong to the port, not the
parser). Reconnect marks are replayed as ``stats.reconnects`` increments, which the odometer
parser watches.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from drivers import encoder, gauge, novatel
from drivers.rawlog import IN, RECONNECT, read_rawlog
from drivers.stats import Stats


def replay(path: str | Path, make_parser: Callable[[Stats], object]) -> tuple[list, Stats]:
    """Feed the received chunks of ``path`` through ``make_parser(stats)``.

    Returns
    -------
    records : everything the parser produced, in order (IMU batches are returned as a list of
        :class:`drivers.novatel.ImuFrames`; join them with ``ImuFrames.concat``).
    stats : the parser's counters.
    """
    stats = Stats()
    parser = make_parser(stats)
    out: list = []
    for d, t, data in read_rawlog(path):
        if d == RECONNECT:
            stats.reconnects += 1
            continue
        if d != IN:
            continue
        recs = parser.feed(data, t)
        if isinstance(recs, list):
            out.extend(recs)
        elif len(recs):
            out.append(recs)
    return out, stats


def replay_imu(path: str | Path, rate_hz: float | None = None) -> tuple[novatel.ImuFrames, Stats]:
    """Replay a RAWIMUSXB raw log into one :class:`drivers.novatel.ImuFrames`."""
    recs, stats = replay(path, lambda s: novatel.RawImuParser(s, rate_hz))
    return novatel.ImuFrames.concat(recs), stats


def replay_encoder(path: str | Path, cfg: encoder.OdometerConfig = encoder.OdometerConfig()) -> tuple[list, Stats]:
    """Replay an odometer raw log into :class:`drivers.encoder.EncoderRecord` s."""
    return replay(path, lambda s: encoder.EncoderParser(s, cfg))


def replay_gauge(path: str | Path) -> tuple[list, Stats]:
    """Replay a gauge raw log into :class:`drivers.gauge.GaugeRecord` s."""
    return replay(path, gauge.GaugeParser)
