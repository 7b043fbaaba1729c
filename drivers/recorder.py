"""Record IMU, odometer and gauge together for a while: links, polling, raw logs, SI arrays.

Times: every record carries the host monotonic time of the read that completed it. The IMU and
the gauge sensor also carry device time; their output times are the device times shifted onto
the host clock by the smallest observed latency (``t = t_dev + min(t_host - t_dev)``), which
removes the batching jitter of serial reads. Odometer times are the reply arrival times (when
several replies arrive in one read, only the latest count is kept for that time).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivers import encoder, gauge, novatel
from drivers.serialport import CLOCK, SerialLink
from drivers.stats import Stats


@dataclass(frozen=True)
class RecordConfig:
    """What to record.

    Attributes
    ----------
    imu_port, odometer_port, gauge_port : serial ports (odometer and gauge optional).
    seconds : how long to record (host time).
    raw_dir : folder for the raw byte logs (None: no raw logs).
    imu_axes : IMU-to-FRD axis map (``novatel.axis_matrix``).
    imu_type : IMU type for the scale table (None: taken from the frames).
    imu_rate_hz : data rate for the increment scaling and the gap count (None: inferred from
        the frames' time steps, ``novatel.rate_from_times``; the IMU type's rate if too few).
    odometer : odometer settings.
    imu_baud, odometer_baud, gauge_baud : line speeds.
    idle_timeout_s : a silence of a streaming device longer than this counts as a timeout.
    """

    imu_port: str
    seconds: float
    odometer_port: str | None = None
    gauge_port: str | None = None
    raw_dir: Path | None = None
    imu_axes: str = "x,y,z"
    imu_type: int | None = None
    imu_rate_hz: float | None = None
    odometer: encoder.OdometerConfig = field(default_factory=encoder.OdometerConfig)
    imu_baud: int = 460800
    odometer_baud: int = encoder.DEFAULT_BAUD
    gauge_baud: int = gauge.DEFAULT_BAUD
    idle_timeout_s: float = 1.0


@dataclass
class Recording:
    """Recorded arrays (times in s from the start of the recording, SI values) and counters."""

    imu_t_s: np.ndarray
    imu_w_rad_s: np.ndarray
    imu_f_m_s2: np.ndarray
    odo_t_s: np.ndarray | None
    odo_distance_m: np.ndarray | None
    gauge_t_s: np.ndarray | None
    gauge_m: np.ndarray | None
    stats: dict[str, Stats]
    imu_type: int | None = None


def align_device_time(t_dev: np.ndarray, t_host: np.ndarray) -> np.ndarray:
    """Device times mapped onto the host clock by the smallest observed latency."""
    if t_dev.size == 0:
        return t_dev.astype(float)
    return t_dev + np.min(t_host - t_dev)


def imu_si(frames: novatel.ImuFrames, cfg: RecordConfig,
           rate_hz: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, int | None]:
    """(t_host-aligned device time, w, f, imu type) of IMU frames.

    ``rate_hz`` (e.g. inferred by the parser) scales the increments when ``cfg.imu_rate_hz``
    is not given; with neither, the IMU type's nominal rate is used.
    """
    if len(frames) == 0:
        return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), cfg.imu_type
    imu_type = cfg.imu_type if cfg.imu_type is not None else int(frames.imu_type[0])
    scale = novatel.imu_scale(imu_type, cfg.imu_rate_hz or rate_hz)
    w, f = frames.to_si(scale, novatel.axis_matrix(cfg.imu_axes))
    g = frames.seconds_since(frames.week[0], frames.sow_s[0])
    t = align_device_time(g, frames.t_host_s)
    return t, w, f, imu_type


def record(cfg: RecordConfig, stop: threading.Event | None = None) -> Recording:
    """Open the ports, record ``cfg.seconds``, close; return arrays and counters.

    Raises
    ------
    drivers.serialport.PortNotFound : a port does not open (message names it).
    drivers.encoder.CounterWidthMismatch : the counter replies in another counter width than
        ``cfg.odometer.bits`` (the raw logs are kept; the message names ``--odometer-bits``).
    """
    novatel.axis_matrix(cfg.imu_axes)  # fail early on a bad map
    raw = Path(cfg.raw_dir) if cfg.raw_dir else None
    links: dict[str, SerialLink] = {}
    imu_parser = novatel.RawImuParser(Stats(), cfg.imu_rate_hz)
    links["imu"] = SerialLink(cfg.imu_port, imu_parser, "imu", cfg.imu_baud,
                              raw / "imu.rawlog" if raw else None, idle_timeout_s=cfg.idle_timeout_s)
    if cfg.odometer_port:
        links["odometer"] = SerialLink(cfg.odometer_port, encoder.EncoderParser(Stats(), cfg.odometer),
                                       "odometer", cfg.odometer_baud, raw / "odometer.rawlog" if raw else None)
    if cfg.gauge_port:
        links["gauge"] = SerialLink(cfg.gauge_port, gauge.GaugeParser(Stats()), "gauge", cfg.gauge_baud,
                                    raw / "gauge.rawlog" if raw else None, idle_timeout_s=cfg.idle_timeout_s)
    poller = None
    try:
        for link in links.values():
            link.open()
        t0 = CLOCK()
        for link in links.values():
            link.start()
        if "odometer" in links:
            poller = encoder.OdometerPoller(links["odometer"], cfg.odometer).start()
        stop = stop or threading.Event()
        stop.wait(cfg.seconds)
    finally:
        if poller:
            poller.stop()
        time.sleep(0.05)  # let the last replies arrive
        for link in links.values():
            link.stop()
    frames = novatel.ImuFrames.concat(links["imu"].drain())
    t, w, f, imu_type = imu_si(frames, cfg, imu_parser.rate)
    odo_t = odo_d = g_t = g_m = None
    if "odometer" in links:
        mismatch = encoder.width_mismatch_error(links["odometer"].stats, cfg.odometer, cfg.odometer_port)
        if mismatch is not None:
            raise mismatch
        recs = links["odometer"].drain()
        c = np.array([r.count1 if cfg.odometer.channel == 1 else r.count2 for r in recs], np.int64)
        odo_t = np.array([r.t_host_s for r in recs], float) - t0
        odo_d = encoder.distance_m(c, cfg.odometer, [r.segment for r in recs])
        # replies that arrived in one read share a host time: keep the latest count of each time
        keep = np.append(np.diff(odo_t) > 0, True) if odo_t.size else np.zeros(0, bool)
        odo_t, odo_d = odo_t[keep], odo_d[keep]
    if "gauge" in links:
        recs = [r for r in links["gauge"].drain() if r.status == gauge.STATUS_OK]
        ms = encoder.unwrap_counts(np.array([r.t_device_ms for r in recs], np.int64), 32) * 1e-3
        g_t = align_device_time(ms, np.array([r.t_host_s for r in recs], float)) - t0
        g_m = np.array([r.gauge_m for r in recs], float)
    return Recording(t - t0 if t.size else t, w, f, odo_t, odo_d, g_t, g_m,
                     {k: l.snapshot() for k, l in links.items()}, imu_type)
