"""Acquisition of a field session: device links, raw bytes and decoded records into the store.

Every read of every port goes, as read, to the project store (``RecordWriter.append``, table
``raw_chunk``, device ``imu``, ``odometer``, ``gauge``, ``totalstation``) before it is parsed, and
every write (odometer polls, GeoCOM requests) as device ``<name>>``; the decoded samples, in session time and SI, go to
``imu_sample``, ``odometer_sample`` and ``gauge_sample`` and to in-memory arrays for the live
processing. The writer commits at least twice a second, so a crash loses at most that much.

Session time: see :class:`TimeBase`. A device is *healthy* while its port is open and its data
keep coming; the session pauses itself when one is not (``Acquisition.faults``).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, replace

import numpy as np

from drivers import encoder, gauge, novatel
from drivers.serialport import SerialLink
from drivers.stats import Stats
from survey.store import GaugeRecord, ImuRecord, OdometerRecord

#: line speeds of the streaming devices unless the devices file gives them (``<device>_baud``): those
#: of the drivers and of ``trolley devices record`` (the odometer and the gauge were opened at 9600,
#: a counter module or gauge sensor at its 115200 default then sent nothing readable)
DEFAULT_BAUDS = {"imu": 460800, "odometer": encoder.DEFAULT_BAUD, "gauge": gauge.DEFAULT_BAUD}
#: the gauge sensor's clock restarted (or jumped) when its step between readings differs from the
#: host clock's by more than this, s (a read batches at most a few tens of ms)
GAUGE_CLOCK_BREAK_S = 2.0
#: a device whose data stop for this long (wall clock) is reported as failing
STALE_AFTER_S = 1.0
#: on resume, monotonic and wall clock must agree this well for the host to count as not restarted
#: (the wall clock may be stepped by NTP; a reboot restarts the monotonic clock by far more)
CLOCK_AGREEMENT_S = 5.0
#: a new time segment after a host restart begins at least this long after the last stored sample
RESUME_GAP_S = 1.0


class RawTap:
    """A parser wrapper that hands every read to the store before parsing it."""

    def __init__(self, inner, device: str, sink) -> None:
        self.inner = inner
        self.stats = inner.stats
        self.device = device
        self.sink = sink  # callable(device, t_host, bytes)

    def feed(self, data: bytes, t_host: float):
        self.sink(self.device, t_host, data)
        return self.inner.feed(data, t_host)


class TappedLink(SerialLink):
    """A serial link whose writes (polls, requests) also go to the store, as device ``<name>>``."""

    def __init__(self, *args, sink=None, **kw) -> None:
        super().__init__(*args, **kw)
        self.sink = sink

    def write(self, data: bytes) -> float:
        t = super().write(data)
        if self.sink is not None:
            self.sink(f"{self.name}>", t, data)
        return t


def tap_writes(link: SerialLink, sink) -> None:
    """Send what ``link`` writes to ``sink`` too (a link made elsewhere, e.g. the total station's)."""
    write = link.write

    def tapped(data: bytes) -> float:
        t = write(data)
        sink(f"{link.name}>", t, data)
        return t

    link.write = tapped


@dataclass
class TimeBase:
    """How device times become session time (seconds since the session started).

    Attributes
    ----------
    imu_week, imu_sow0_s : GPS time of session time 0 (IMU: ``t = gps - that``).
    gauge_origin_s : session time of the gauge's millisecond clock zero.
    odo_count0 : counter reading at odometer distance 0.
    host_t0 : monotonic host time of session time 0 (odometer replies in a real session). Only
        meaningful while the host runs: a reboot restarts the monotonic clock (:meth:`resumed`).
    wall_t0 : wall-clock time (``time.time()``, s since 1970) of session time 0; None in sessions
        recorded before it was kept.
    odometer_time : in a simulated session, the session time of the k-th poll (None: host time).
    """

    imu_week: int | None = None
    imu_sow0_s: float | None = None
    gauge_origin_s: float | None = None
    odo_count0: int | None = None
    host_t0: float = field(default_factory=time.monotonic)
    odometer_time: object = None
    wall_t0: float | None = None

    def __post_init__(self) -> None:
        if self.wall_t0 is None and self.odometer_time is None:
            # the same instant on both clocks, read together
            self.wall_t0 = time.time() - (time.monotonic() - self.host_t0)

    def to_json(self) -> dict:
        return {"imu_week": self.imu_week, "imu_sow0_s": self.imu_sow0_s, "odo_count0": self.odo_count0,
                "host_t0": self.host_t0, "wall_t0": self.wall_t0, "gauge_origin_s": self.gauge_origin_s}

    @classmethod
    def from_json(cls, d: dict) -> "TimeBase":
        """The time base a ``clock`` event stored (``wall_t0`` missing in older sessions: None)."""
        tb = cls(imu_week=d["imu_week"], imu_sow0_s=d["imu_sow0_s"], odo_count0=d["odo_count0"],
                 host_t0=d["host_t0"], gauge_origin_s=d.get("gauge_origin_s"), wall_t0=0.0)
        tb.wall_t0 = d.get("wall_t0")
        return tb

    def resumed(self, last_t_s: float) -> tuple["TimeBase", dict | None]:
        """The time base of a real-device session resumed now, after data up to ``last_t_s``.

        Same host run (the monotonic clock still counts from the session's start, and agrees with
        the wall clock within ``CLOCK_AGREEMENT_S``): the same base, re-anchored on the wall clock.
        Otherwise the host restarted (power loss, reboot): session time goes on from the wall clock,
        and never from before the last stored sample (``RESUME_GAP_S`` after it at least, should the
        wall clock be wrong); the device clocks (IMU, gauge) are mapped again from their first data,
        since the devices may have restarted too. Returns the base and, for a new time segment,
        what to record about the gap (None otherwise).
        """
        mono, wall = time.monotonic(), time.time()
        t_mono = mono - self.host_t0
        t_wall = wall - self.wall_t0 if self.wall_t0 is not None else float("nan")
        same_run = t_mono > last_t_s and not abs(t_mono - t_wall) > CLOCK_AGREEMENT_S  # NaN: no wall anchor
        if same_run:
            return replace(self, wall_t0=wall - t_mono), None
        t_now = t_wall if t_wall > last_t_s + RESUME_GAP_S else last_t_s + RESUME_GAP_S
        tb = replace(self, host_t0=mono - t_now, wall_t0=wall - t_now, imu_week=None, imu_sow0_s=None,
                     gauge_origin_s=None)
        gap = {"last_stored_s": last_t_s, "resumed_at_s": t_now, "monotonic_s": t_mono,
               "wall_s": None if t_wall != t_wall else t_wall,
               "why": "the host clock restarted (reboot or power loss): a new time segment"}
        return tb, gap


@dataclass
class DeviceHealth:
    """What the live screen shows per device."""

    name: str
    connected: bool
    last_data_age_s: float
    samples: int
    errors: int
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.connected and self.last_data_age_s < STALE_AFTER_S


class Buffers:
    """Growing in-memory copies of the decoded samples: arrays whose capacity doubles, so appending
    is amortised O(1) and reading is a view (a reader keeps a consistent prefix while rows are added)."""

    WIDTH = {"imu": 7, "odo": 2, "gauge": 2}  # t + values

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self._data = {k: np.zeros((1024, w)) for k, w in self.WIDTH.items()}
        self._n = {k: 0 for k in self.WIDTH}

    def add(self, kind: str, rows: np.ndarray) -> None:
        m = rows.shape[0]
        if not m:
            return
        with self.lock:
            a, n = self._data[kind], self._n[kind]
            if n + m > a.shape[0]:
                b = np.zeros((max(2 * a.shape[0], n + m), a.shape[1]))
                b[:n] = a[:n]
                self._data[kind] = a = b
            a[n:n + m] = rows
            self._n[kind] = n + m

    def array(self, kind: str, width: int | None = None) -> np.ndarray:
        """All rows so far (a read-only view)."""
        with self.lock:
            v = self._data[kind][: self._n[kind]].view()
        v.flags.writeable = False
        return v

    def tail(self, kind: str, seconds: float) -> np.ndarray:
        """The rows of the last ``seconds`` (by their time column)."""
        a = self.array(kind)
        if a.shape[0] == 0:
            return a
        i = int(np.searchsorted(a[:, 0], a[-1, 0] - seconds, side="left"))
        return a[i:]

    def last_t(self, kind: str) -> float:
        with self.lock:
            n = self._n[kind]
            return float(self._data[kind][n - 1, 0]) if n else float("-inf")


class SimOdometerPoller:
    """Polls the simulated counter module on the simulation's schedule: every poll whose time has
    come is sent at once, and the k-th reply is stamped with the k-th poll's session time."""

    def __init__(self, link: SerialLink, world) -> None:
        self.link = link
        self.world = world
        self.polls = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-odometer-poll", daemon=True)

    def start(self) -> "SimOdometerPoller":
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            now = self.world.now()
            n = 0
            while self.world.odometer_time(self.polls + n) <= now and n < 2000 and \
                    self.world.odometer_time(self.polls + n) < self.world.duration_s + 1e-9 and \
                    (self.polls + n) + self.world.odo_first_index < self.world.sim.session.odo_t_s.size:
                n += 1
            if n:
                try:
                    self.link.write(encoder.READ_COMMAND * n)
                    self.polls += n
                except Exception:  # port gone: the link reconnects; polls resume when it is back
                    pass
            self._stop.wait(0.004)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


class Acquisition:
    """The three streaming devices of a session: links, time base, store writes, buffers, health.

    Parameters
    ----------
    ports : device -> serial port ("imu" required; "odometer", "gauge" optional).
    writer : the session's ``RecordWriter`` (raw bytes and decoded records).
    timebase : device time -> session time.
    world : the simulated world (simulated session) or None.
    odometer : counter settings.
    imu_type, imu_rate_hz, imu_axes : IMU scale and mounting.
    bauds : device -> line speed, default :data:`DEFAULT_BAUDS` (the drivers' and ``devices record``'s).
    """

    def __init__(self, ports: dict[str, str], writer, timebase: TimeBase, world=None,
                 odometer: encoder.OdometerConfig = encoder.OdometerConfig(), imu_type: int | None = None,
                 imu_rate_hz: float | None = None, imu_axes: str = "x,y,z", bauds: dict[str, int] | None = None) -> None:
        self.writer = writer
        self.tb = timebase
        self.world = world
        self.odo_cfg = odometer
        self.imu_type = imu_type
        self.imu_rate_hz = imu_rate_hz
        self.axes = novatel.axis_matrix(imu_axes)
        self.buffers = Buffers()
        self.write_error: str = ""
        self.links: dict[str, SerialLink] = {}
        mk = {"imu": lambda: novatel.RawImuParser(Stats(), imu_rate_hz),
              "odometer": lambda: encoder.EncoderParser(Stats(), self._odo_parser_cfg()),
              "gauge": lambda: gauge.GaugeParser(Stats())}
        for name, port in ports.items():
            if name in mk:
                self.links[name] = TappedLink(port, RawTap(mk[name](), name, self._raw), name,
                                              baudrate={**DEFAULT_BAUDS, **(bauds or {})}[name], sink=self._raw)
        self.last_data_host: dict[str, float] = {k: time.monotonic() for k in self.links}
        self.samples: dict[str, int] = {k: 0 for k in self.links}
        self.dropped: dict[str, int] = {}
        self._odo_reply_index = 0
        self._odo_skipped = 0
        #: (parser segment, counter reading, distance there) the distance of new replies counts from
        self._odo_base: tuple[int, int, float] | None = None
        self._odo_last_d = 0.0
        self._gauge_unwrap: tuple[int, int] | None = None  # (last raw ms, accumulated)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._pump_lock = threading.Lock()
        self.poller = None

    def _odo_parser_cfg(self) -> encoder.OdometerConfig:
        if self.world is None:
            return self.odo_cfg
        from dataclasses import replace
        # the parser's speed gate runs on host time, which a simulation compresses
        return replace(self.odo_cfg, max_speed_m_s=self.odo_cfg.max_speed_m_s * self.world.options.speedup)

    def _raw(self, device: str, t_host: float, data: bytes) -> None:
        try:
            self.writer.append(device, t_host, data)
        except Exception as exc:  # reported on the screen; the queue keeps the rows
            self.write_error = str(exc)

    # ------------------------------------------------------------------ lifecycle
    def open(self, timeout_s: float = 5.0) -> None:
        """Open every port (``drivers.serialport.PortNotFound`` names the one that fails)."""
        for link in self.links.values():
            link.open(timeout_s)

    def start(self) -> None:
        for link in self.links.values():
            link.start()
        if "odometer" in self.links:
            if self.world is not None:
                self.poller = SimOdometerPoller(self.links["odometer"], self.world).start()
            else:
                self.poller = encoder.OdometerPoller(self.links["odometer"], self.odo_cfg).start()
        self._thread = threading.Thread(target=self._run, name="acquisition", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        if self.poller is not None:
            self.poller.stop()
        time.sleep(0.05)
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for link in self.links.values():
            link.stop()
        self.pump()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.pump()
            except Exception as exc:  # never let the pump die silently; shown on the screen
                self.write_error = f"acquisition: {exc}"
            self._stop.wait(0.02)

    # ------------------------------------------------------------------ decoding
    def pump(self) -> None:
        """Move everything the links decoded into the store and the buffers (any thread; one at a time,
        since the odometer's reply index and the device clocks are carried from batch to batch)."""
        with self._pump_lock:
            self._pump()

    def _pump(self) -> None:
        now = time.monotonic()
        if "imu" in self.links:
            batches = self.links["imu"].drain()
            if batches:
                self._imu(novatel.ImuFrames.concat(batches))
                self.last_data_host["imu"] = now
        if "odometer" in self.links:
            recs = self.links["odometer"].drain()
            if recs:
                self._odometer(recs)
                self.last_data_host["odometer"] = now
        if "gauge" in self.links:
            recs = self.links["gauge"].drain()
            if recs:
                self._gauge(recs)
                self.last_data_host["gauge"] = now

    def _imu(self, fr: novatel.ImuFrames) -> None:
        imu_type = self.imu_type if self.imu_type is not None else int(fr.imu_type[0])
        w, f = fr.to_si(novatel.imu_scale(imu_type, self.imu_rate_hz), self.axes)
        if self.tb.imu_week is None:  # first frames of a real session: smallest latency
            self.tb.imu_week = int(fr.week[0])
            dev = fr.seconds_since(fr.week[0], 0.0)
            self.tb.imu_sow0_s = float(np.min(dev - (fr.t_host_s - self.tb.host_t0)))
        t = fr.seconds_since(self.tb.imu_week, self.tb.imu_sow0_s)
        rows = np.column_stack([t, w, f])
        self._store("imu_sample", ImuRecord, rows)
        self.buffers.add("imu", rows)
        self.samples["imu"] += rows.shape[0]

    def _odometer(self, recs) -> None:
        c = np.array([r.count1 if self.odo_cfg.channel == 1 else r.count2 for r in recs], np.int64)
        if self.world is not None:
            # the k-th reply answers the k-th poll, whether the parser kept it or not: replies it
            # withheld (no anchor yet: the first ``confirm - 1`` after (re)connecting) or rejected
            # are counted too. They precede the records drained here (a confirmed record comes
            # after the replies that confirmed it); the simulated counter sends no corrupt reply.
            st = self.links["odometer"].stats
            skipped = int(st.extra.get("unconfirmed", 0) + st.bad_format + st.bad_checksum)
            self._odo_reply_index += skipped - self._odo_skipped
            self._odo_skipped = skipped
            k = self._odo_reply_index + np.arange(c.size)
            t = np.array([self.world.odometer_time(int(i)) for i in k])
            self._odo_reply_index += c.size
        else:
            t = np.array([r.t_host_s for r in recs], float) - self.tb.host_t0
        if self.tb.odo_count0 is None:
            self.tb.odo_count0 = int(c[0])
        if self._odo_base is None:
            self._odo_base = (recs[0].segment, self.tb.odo_count0, 0.0)
        d = np.empty(c.size)
        mpc = self.odo_cfg.metres_per_count
        segment = np.array([r.segment for r in recs])
        # runs of one parser segment (a new one is rare: numpy per run, not a loop per reply)
        starts = np.flatnonzero(np.r_[segment[0] != self._odo_base[0], segment[1:] != segment[:-1]])
        edges = np.r_[0, starts, c.size]
        for i, j in zip(edges[:-1], edges[1:]):
            if j <= i:
                continue
            seg, c0, d0 = self._odo_base
            if segment[i] != seg:
                # the parser re-anchored on readings that do not continue the old ones (a counter
                # restarted at 0 by a power-cycled unplug): the distance carries on from the last
                # reply (it jumped back by the whole count, and the session saw the trolley move)
                last = d[i - 1] if i else self._odo_last_d
                self._odo_base = seg, c0, d0 = int(segment[i]), int(c[i]), float(last)
            d[i:j] = d0 + encoder.signed_delta(c[i:j], c0, self.odo_cfg.bits) * mpc
        self._odo_last_d = float(d[-1])
        keep = np.append(np.diff(t) > 0, True)  # replies of one read share a host time
        rows = np.column_stack([t[keep], d[keep]])
        last = self.buffers.last_t("odo")
        late = rows[:, 0] <= last
        if np.any(late):  # never silently: a time base that went backwards shows on the screen
            self.dropped["odometer"] = self.dropped.get("odometer", 0) + int(late.sum())
            self.write_error = (f"odometer: {self.dropped['odometer']} replies timed before the stored data "
                                "were not stored")
        rows = rows[~late]
        self._store("odometer_sample", OdometerRecord, rows)
        self.buffers.add("odo", rows)
        self.samples["odometer"] += rows.shape[0]

    def _gauge(self, recs) -> None:
        """Gauge readings on session time: the sensor's millisecond clock (unwrapped), shifted onto
        the host clock by the smallest latency seen. Where the clock does not go on as the host's
        (it went back, or moved GAUGE_CLOCK_BREAK_S more or less than the host clock: the sensor
        restarted after an unplug, or while a resumed session was down) a new clock segment
        starts, shifted again: it restarts at 0, and its readings were stored up to its whole
        uptime in the past, out of time order."""
        recs = [r for r in recs if r.status == gauge.STATUS_OK]
        if not recs:
            return
        ms = np.array([r.t_device_ms for r in recs], np.int64)
        th = np.array([r.t_host_s for r in recs], float) - self.tb.host_t0
        first = self._gauge_unwrap is None
        prev, acc, prev_th = (int(ms[0]), int(ms[0]), th[0]) if first else self._gauge_unwrap
        seq = np.concatenate([[prev], ms])
        h = gauge.MS_MODULO // 2
        steps = (seq[1:] - seq[:-1] + h) % gauge.MS_MODULO - h  # the device clock wraps
        cum = acc + np.cumsum(steps)
        host_steps = np.diff(np.concatenate([[prev_th], th]))
        brk = (steps < 0) | (np.abs(steps * 1e-3 - host_steps) > GAUGE_CLOCK_BREAK_S)
        last = self.buffers.last_t("gauge")
        real = self.world is None  # simulated: the twin's clock is the simulated one, its origin given
        if not real:
            brk[:] = False
        if self.tb.gauge_origin_s is None:
            brk[0] = True
        elif first and real:
            # a resumed session: the sensor may have restarted while it was down
            t0 = self.tb.gauge_origin_s + cum[0] * 1e-3
            brk[0] = brk[0] or t0 <= last or abs(th[0] - t0) > GAUGE_CLOCK_BREAK_S
        self._gauge_unwrap = (int(ms[-1]), int(cum[-1]), float(th[-1]))
        t = np.empty(cum.size)
        starts = np.flatnonzero(brk)
        edges = np.concatenate([[0], starts, [cum.size]])
        for i, j in zip(edges[:-1], edges[1:]):
            if j <= i:
                continue
            if brk[i]:  # a new clock segment: shifted by its own smallest latency (in this batch)
                self.tb.gauge_origin_s = float(np.min(th[i:j] - cum[i:j] * 1e-3))
            t[i:j] = self.tb.gauge_origin_s + cum[i:j] * 1e-3
        rows = np.column_stack([t, [r.gauge_m for r in recs]])
        late = rows[:, 0] <= np.maximum.accumulate(np.concatenate([[last], rows[:-1, 0]]))
        if real and np.any(late):  # never silently, as the odometer's
            self.dropped["gauge"] = self.dropped.get("gauge", 0) + int(late.sum())
            self.write_error = f"gauge: {self.dropped['gauge']} readings timed before the stored data were not stored"
            rows = rows[~late]
        self._store("gauge_sample", GaugeRecord, rows)
        self.buffers.add("gauge", rows)
        self.samples["gauge"] += rows.shape[0]

    def _store(self, table: str, cls, rows: np.ndarray) -> None:
        if not rows.shape[0]:
            return
        try:
            self.writer.append_records(table, [cls(*r) for r in rows.tolist()])
        except Exception as exc:
            self.write_error = str(exc)

    # ------------------------------------------------------------------ health
    def health(self) -> list[DeviceHealth]:
        now = time.monotonic()
        out = []
        for name, link in self.links.items():
            st = link.stats
            errors = st.bad_checksum + st.bad_format + st.timeouts
            connected = link.connected.is_set()
            age = now - self.last_data_host[name]
            msg = "" if connected else (link.last_error or "port gone")
            if connected and age >= STALE_AFTER_S:
                msg = f"no data for {age:.1f} s"
            out.append(DeviceHealth(name, connected, age, self.samples[name], errors, msg))
        return out

    def faults(self) -> list[DeviceHealth]:
        """Devices that are not healthy now."""
        return [h for h in self.health() if not h.ok]
