"""The simulated site: the truth simulator's survey streamed by the device twins over real ptys.

The IMU, odometer and gauge twins stream the simulated samples paced by one shared clock that runs
``speedup`` times faster than the wall clock; the total-station twin is aimed at the CPIII prisms
during the station setup and at the simulated prism position of the current stop for a fix. A
resumed session restarts the twins just after the last sample the store holds, so the simulated
world continues exactly where the record ends.

Session time is the simulator's time: the IMU's GPS time minus ``IMU_SOW0``, the gauge sensor's
millisecond clock plus the time of its first streamed sample, and the odometer's k-th poll at the
k-th odometer sample time (the counter module has no clock; in a simulation the poll schedule is
the clock).
"""
from __future__ import annotations

import contextlib
import math
import shutil
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from drivers import encoder, novatel
from drivers.twins.gauge import GaugeTwin
from drivers.twins.imu import ImuTwin
from drivers.twins.odometer import OdometerTwin
from drivers.twins.totalstation import TotalStationTwin

#: NovAtel IMU type streamed by the twin (ISA-100C: 1e-9 rad per count, no visible quantisation)
SIM_IMU_TYPE = 26
#: GPS week and seconds of week of session time 0
IMU_WEEK, IMU_SOW0 = 2300, 100000.0
#: odometer counter whose count equals the simulator's quantised distance (1e-4 m per count)
SIM_ODOMETER = encoder.OdometerConfig(ppr=1024, decode=4, wheel_diameter_m=0.4096 / math.pi)


@dataclass(frozen=True)
class SimOptions:
    """How the simulated site runs.

    Attributes
    ----------
    speedup : simulated seconds per wall-clock second.
    angle_sigma_rad, distance_sigma_m : the total-station twin's reading noise (Hz and V; slope
        distance), for the station setup and the fixes alike: the truth the fix sigmas are checked
        against, independent of the project's a priori sigmas.
    station_offset_m : the instrument stands this far to the left of the track, ``station_ahead_m``
        ahead of the first stop.
    orientation_rad : the instrument's unknown circle orientation.
    seed : noise seed of the total station (fix noise is seeded per stop and attempt).
    fix_blunders_m : ``(stop, attempt, dE, dN, dH)`` rows: that attempt at a fix at that stop
        (0-based, as seeded) is off by (dE, dN, dH) m, a blunder for the innovation test.
    cpiii_prism_constant_m, trolley_prism_constant_m : Leica additive constants of the site's
        physical CPIII prisms and trolley prism (the project's settings, unless a test gives the
        site other prisms than the project states).
    """

    speedup: float = 1.0
    angle_sigma_rad: float = 2.4e-6
    distance_sigma_m: float = 0.0006
    station_offset_m: float = 3.0
    station_ahead_m: float = 40.0
    orientation_rad: float = 1.2345
    seed: int = 7
    fix_blunders_m: tuple[tuple[int, int, float, float, float], ...] = ()
    cpiii_prism_constant_m: float = 0.0
    trolley_prism_constant_m: float = 0.0


class SimClock:
    """Session time of the simulated world: ``t0_s + speedup * (monotonic() - start)``."""

    def __init__(self, t0_s: float, speedup: float) -> None:
        self.t0_s = float(t0_s)
        self.speedup = float(speedup)
        self.start_monotonic = time.monotonic()
        self.frozen_at: float | None = None
        self.limit: float | None = None  # simulated time stands at this limit until it is raised
        self._lock = threading.Lock()

    def now(self) -> float:
        if self.frozen_at is not None:
            return self.frozen_at
        with self._lock:
            t = self.t0_s + self.speedup * (time.monotonic() - self.start_monotonic)
            if self.limit is not None and t > self.limit:
                # stand at the limit: the time past it is not lost, it never happened
                self.start_monotonic = time.monotonic() - (self.limit - self.t0_s) / self.speedup
                t = self.limit
            return t

    def freeze(self) -> None:
        """Stop simulated time (the world waits for the crew). Nested: one ``thaw`` per ``freeze``."""
        self.holds = getattr(self, "holds", 0) + 1
        if self.frozen_at is None:
            self.frozen_at = self.now()

    def thaw(self) -> None:
        """Let simulated time run on from where it was frozen, once every ``freeze`` is thawed."""
        self.holds = max(getattr(self, "holds", 0) - 1, 0)
        if self.frozen_at is not None and self.holds == 0:
            self.start_monotonic = time.monotonic() - (self.frozen_at - self.t0_s) / self.speedup
            self.frozen_at = None

    @property
    def frozen(self) -> bool:
        return self.frozen_at is not None

    @property
    def standing_still(self) -> bool:
        """Simulated time does not run: frozen, or standing at its limit (the streams wait too)."""
        return self.frozen or (self.limit is not None and self.now() >= self.limit)

    def host_at(self, t_s: float) -> float:
        """Monotonic host time at which session time ``t_s`` comes."""
        return self.start_monotonic + (t_s - self.t0_s) / self.speedup


class _PacedImuTwin(ImuTwin):
    """ImuTwin paced by the shared simulation clock (frames sent when their time has come)."""

    def __init__(self, clock: SimClock, t_s, *args, **kw) -> None:
        self.sim_clock = clock
        self.t_abs = np.asarray(t_s, float)
        super().__init__(t_s, *args, **kw)

    def serve(self) -> None:
        L = novatel.FRAME_LEN
        i, n = 0, self.n_frames
        while i < n and not self.stopped:
            j = int(np.searchsorted(self.t_abs, self.sim_clock.now(), side="right"))
            if j <= i:
                time.sleep(0.004)
                continue
            if not self.send(self.stream[i * L: j * L]) and not self.stopped:
                self.wait_ready()  # unplugged: those frames are lost, like on a real unplug
            i = j
            self.frames_sent = i


class _PacedGaugeTwin(GaugeTwin):
    """GaugeTwin paced by the shared simulation clock."""

    def __init__(self, clock: SimClock, t_s, *args, **kw) -> None:
        self.sim_clock = clock
        self.t_abs = np.asarray(t_s, float)
        super().__init__(t_s, *args, **kw)

    def serve(self) -> None:
        i, n = 0, len(self.lines)
        while i < n and not self.stopped:
            j = int(np.searchsorted(self.t_abs, self.sim_clock.now(), side="right"))
            if j <= i:
                time.sleep(0.01)
                continue
            if not self.send(b"".join(self.lines[i:j])) and not self.stopped:
                self.wait_ready()
            i = j
            self.lines_sent = i


def prism_position_enh(sim, t_s: float) -> np.ndarray:
    """Grid E, N, H of the prism at simulated time ``t_s`` (no measurement noise).

    The same construction as the simulator's fixes: track reference point plus the prism lever
    arm rotated by the trolley attitude (ZYX Euler, NED), mapped NED -> ENH.
    """
    geo, motion = sim.truth.geometry, sim.truth.motion
    s = motion.evaluate(np.array([float(t_s)]))[0]
    p = geo.position(s)[0]
    r, pch, y = (float(a[0]) for a in geo.attitude(s))
    # a trolley the crew handles (turned around, lifted): the simulator's own rotation of it
    from trolley.truthsim import handling_quat

    w, x, yq, z = handling_quat(motion, np.array([float(t_s)]))[0]
    turned = Rotation.from_euler("ZYX", [y, pch, r]) * Rotation.from_quat([x, yq, z, w])
    lever_n = turned.apply(np.asarray(sim.config.trolley.prism_lever_arm_m, float))
    return geo.grid_enh(np.array([p[0] + lever_n[1], p[1] + lever_n[0], p[2] - lever_n[2]]))


#: the simulated trolley still stands this long after a stop's scripted end: it starts gently
#: (5 um after 0.1 s at 2 m/s), and an interactive world waits for the crew at the first stop a
#: moment past its end, until the static alignment has its data
STOP_GRACE_S = 0.1


def stop_index_at(sim, t_s: float) -> int:
    """Index of the stop the simulated trolley stands at at ``t_s`` (up to ``STOP_GRACE_S`` past
    its scripted end), or -1 while it moves."""
    m = sim.truth.motion
    k = np.flatnonzero((m.stop_start_s <= t_s) & (t_s <= m.stop_end_s + STOP_GRACE_S))
    return int(k[0]) if k.size else -1


class SimWorld:
    """The simulated site around one session.

    Parameters
    ----------
    sim : ``trolley.truthsim.SimulatedSurvey`` of the project.
    options : speed-up and noise.
    """

    def __init__(self, sim, options: SimOptions = SimOptions()) -> None:
        self.sim = sim
        self.options = options
        self.clock: SimClock | None = None
        self.twins: dict = {}
        self.fix_attempts: dict[int, int] = {}
        self.setup_attempts: dict[tuple, int] = {}
        self.setup_k = 0  # the station setup the instrument stands for (its circle orientation)
        raw = sim.session
        self.gauge_t0_s = 0.0
        # instrument beside the track, a little ahead of the first stop
        geo = sim.truth.geometry
        s0 = float(sim.truth.motion.stop_chainage_m[0]) + options.station_ahead_m
        s0 = min(s0, float(geo.end_chainage_m))
        p = geo.position(np.array([s0]))[0]
        yaw = float(geo.attitude(np.array([s0]))[2][0])
        left = np.array([-math.cos(yaw), math.sin(yaw)])  # (E, N) to the left of the heading
        self.station_enh_m = geo.grid_enh(np.array([p[0] + options.station_offset_m * left[0],
                                                    p[1] + options.station_offset_m * left[1], p[2] + 1.2]))
        self.duration_s = float(max(raw.imu_t_s[-1], raw.odo_t_s[-1]))

    # ------------------------------------------------------------------ lifecycle
    def start(self, t_start_s: float = 0.0, after: dict[str, float] | None = None) -> dict[str, str]:
        """Create the twins streaming from session time ``t_start_s``; returns device -> port.

        ``after``: per device, the last sample time already stored (a resumed session); each twin
        starts with the first sample after it.
        """
        after = after or {}
        raw = self.sim.session
        self.clock = SimClock(t_start_s, self.options.speedup)
        # stored times carry the rounding of the time bases: 1 us tolerance (samples are >= 1 ms apart)
        i0 = int(np.searchsorted(raw.imu_t_s, after.get("imu", -np.inf) + 1e-6, side="right"))
        k0 = int(np.searchsorted(raw.odo_t_s, after.get("odometer", -np.inf) + 1e-6, side="right"))
        if "odometer" in after:
            # the driver withholds the first replies after connecting until they confirm each other
            # (drivers.encoder, ``confirm``): let those be samples already stored, so none is lost
            k0 = max(k0 - (getattr(SIM_ODOMETER, "confirm", 1) - 1), 0)
        g0 = int(np.searchsorted(raw.gauge_t_s, after.get("gauge", -np.inf) + 1e-6, side="right"))
        self.odo_first_index = k0
        # stable paths, like /dev/serial/by-id/...: a twin that is unplugged comes back at the same path
        self.link_dir = Path(tempfile.mkdtemp(prefix="trolley-sim-"))
        link = {k: self.link_dir / k for k in ("imu", "odometer", "gauge", "totalstation")}
        imu = _PacedImuTwin(self.clock, raw.imu_t_s[i0:], raw.imu_w_rad_s[i0:], raw.imu_f_m_s2[i0:],
                            imu_type=SIM_IMU_TYPE, rate_hz=None, week=IMU_WEEK,
                            sow0=IMU_SOW0 + float(raw.imu_t_s[i0]) if i0 < raw.imu_t_s.size else IMU_SOW0,
                            link_path=link["imu"])
        odo = OdometerTwin(raw.odo_t_s[k0:], raw.odo_distance_m[k0:], SIM_ODOMETER, mode="index",
                           link_path=link["odometer"])
        self.gauge_t0_s = float(raw.gauge_t_s[g0]) if g0 < raw.gauge_t_s.size else 0.0
        gauge = _PacedGaugeTwin(self.clock, raw.gauge_t_s[g0:], raw.gauge_m[g0:], link_path=link["gauge"])
        o = self.options
        ts = TotalStationTwin(station=(*self.station_enh_m, 0.0), target=None, noise_angle_rad=o.angle_sigma_rad,
                              noise_dist_m=o.distance_sigma_m, seed=o.seed, link_path=link["totalstation"])
        ts.orientation = o.orientation_rad
        self.twins = {"imu": imu, "odometer": odo, "gauge": gauge, "totalstation": ts}
        return {k: t.port for k, t in self.twins.items()}

    def run_twins(self, wait_client_s: float = 30.0) -> None:
        """Start the twins' workers (each waits until the application has opened its port)."""
        for t in self.twins.values():
            t.start(wait_client_s)

    def stop(self) -> None:
        for t in self.twins.values():
            t.stop()
        if getattr(self, "link_dir", None) is not None:
            shutil.rmtree(self.link_dir, ignore_errors=True)

    # ------------------------------------------------------------------ time
    @contextlib.contextmanager
    def crew_busy(self):
        """Simulated time stands still while the crew measures (a fix, a station change).

        The simulator's motion is scripted in time; a real trolley waits for its crew. Freezing
        the clock makes the measurement happen at one simulated instant whatever the wall-clock
        time it takes, so scripted simulated sessions are reproducible at any ``speedup``.
        """
        self.clock.freeze()
        try:
            yield
        finally:
            self.clock.thaw()

    def now(self) -> float:
        return self.clock.now() if self.clock else 0.0

    def odometer_time(self, k: int) -> float:
        """Session time of the ``k``-th poll since :meth:`start`."""
        t = self.sim.session.odo_t_s
        return float(t[min(self.odo_first_index + k, t.size - 1)])

    def finished(self, t_s: float) -> bool:
        """Whether the simulated data have all arrived by session time ``t_s`` (the last odometer
        poll and the last IMU frame may differ by one IMU period)."""
        raw = self.sim.session
        return t_s >= min(raw.imu_t_s[-1], raw.odo_t_s[-1]) - 1e-9

    # ------------------------------------------------------------------ total station
    def aim_at_point(self, enh_m) -> None:
        """Aim the instrument at a control point (the crew points the telescope, ATR fine-aims).

        The reading noise of this pointing is seeded by (setup, point, attempt), like a fix's, so
        that a station setup measured again after a resume reads the same values as it would
        have in an uninterrupted session."""
        ts = self.twins["totalstation"]
        target = tuple(float(x) for x in enh_m)
        key = (self.setup_k, *(int(round(1e3 * abs(x))) for x in target))
        attempt = self.setup_attempts.get(key, 0)
        self.setup_attempts[key] = attempt + 1
        ts.seed_noise([self.options.seed, 1000, *key, attempt])
        ts.set_target(target, self.options.cpiii_prism_constant_m)

    def move_instrument(self, k: int, chainage_m: float) -> None:
        """Station change: the instrument is set up anew beside the track near ``chainage_m``
        (``station_ahead_m`` ahead), with setup ``k``'s circle orientation and its reading noise."""
        geo = self.sim.truth.geometry
        o = self.options
        s = float(np.clip(chainage_m + o.station_ahead_m, geo.start_chainage_m, geo.end_chainage_m))
        p = geo.position(np.array([s]))[0]
        yaw = float(geo.attitude(np.array([s]))[2][0])
        self.place_instrument(geo.grid_enh(np.array([p[0] - o.station_offset_m * math.cos(yaw),
                                                     p[1] + o.station_offset_m * math.sin(yaw), p[2] + 1.2])), k)

    def place_instrument(self, station_enh_m, k: int) -> None:
        """Put the instrument at ``station_enh_m`` with setup ``k``'s circle orientation (also on resume)."""
        ts = self.twins["totalstation"]
        self.station_enh_m = np.asarray(station_enh_m, float).copy()
        self.setup_k = int(k)
        with ts._lock:
            ts.position = tuple(map(float, self.station_enh_m))  # where it physically stands
            ts.orientation = (self.options.orientation_rad + 0.37 * k) % (2 * math.pi)
        ts.noise_angle_rad = self.options.angle_sigma_rad
        ts.noise_dist_m = self.options.distance_sigma_m

    def restore_fix_attempts(self, fix_times_s) -> None:
        """On resume: count the fixes already measured at each stop (``fix_times_s``, every stored
        fix), so that the next attempt at a stop gets the noise it would have had without the crash."""
        self.fix_attempts = {}
        for t in fix_times_s:
            k = stop_index_at(self.sim, float(t))
            self.fix_attempts[k] = self.fix_attempts.get(k, 0) + 1

    def quiet_instrument(self) -> None:
        """No reading noise until the next pointing: the reading that orients the circle after a
        setup is not a measurement (each fix turns the noise on again, :meth:`aim_at_prism`)."""
        ts = self.twins["totalstation"]
        ts.noise_angle_rad = 0.0
        ts.noise_dist_m = 0.0

    def aim_at_prism(self, t_s: float) -> int:
        """Aim at the trolley's prism at ``t_s``; the twin's reading noise (Hz, V, slope distance, per
        its own sigmas) is the fix noise, seeded per stop and attempt.

        Returns the stop index (-1 if the trolley is moving: the prism where it is).
        """
        ts = self.twins["totalstation"]
        k = stop_index_at(self.sim, t_s)
        attempt = self.fix_attempts.get(k, 0)
        self.fix_attempts[k] = attempt + 1
        ts.seed_noise([self.options.seed, k + 1, attempt])
        ts.noise_angle_rad = self.options.angle_sigma_rad
        ts.noise_dist_m = self.options.distance_sigma_m
        blunder = sum((np.array(b[2:], float) for b in self.options.fix_blunders_m if (b[0], b[1]) == (k, attempt)),
                      np.zeros(3))
        ts.set_target(tuple(prism_position_enh(self.sim, t_s) + blunder), self.options.trolley_prism_constant_m)
        return k
