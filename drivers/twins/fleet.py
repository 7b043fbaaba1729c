"""All four twins at once, fed from one session's arrays or from a synthetic stationary scene.

``trolley devices simulate`` builds a :class:`Fleet`, writes its :meth:`Fleet.ports_json` (the
devices file that ``trolley survey start --devices`` reads) and runs it until interrupted. The
twins share one time origin (:class:`drivers.twins.base.Epoch`), set when the application first
opens one of the ports, so samples of the same session time leave every port at the same host
time. Nothing here reads files: the caller hands over arrays (``survey.sessionio.read_session``).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from drivers import encoder
from drivers.twins.base import Epoch, Faults, PtyTwin

DEVICES = ("imu", "odometer", "gauge", "totalstation")
#: length of the synthetic block that the endless synthetic feed repeats
SYNTHETIC_BLOCK_S = 60.0


@dataclass
class FleetFeed:
    """What the twins send, in session time (s). ``None`` arrays: that twin is not started.

    Attributes
    ----------
    imu_t_s, imu_w_rad_s, imu_f_m_s2 : IMU samples (FRD, SI).
    odo_t_s, odo_distance_m : cumulative odometer distance.
    gauge_t_s, gauge_m : full gauge.
    fix_t_s, fix_enh_m : (K,), (K, 3) prism positions; the total station is aimed at the last
        fix whose time has come (the first one before that).
    station : (E0, N0, H0, Hi) of the total station.
    repeat : loop the streams endlessly (synthetic) or play them once (a session).
    """

    imu_t_s: np.ndarray | None = None
    imu_w_rad_s: np.ndarray | None = None
    imu_f_m_s2: np.ndarray | None = None
    odo_t_s: np.ndarray | None = None
    odo_distance_m: np.ndarray | None = None
    gauge_t_s: np.ndarray | None = None
    gauge_m: np.ndarray | None = None
    fix_t_s: np.ndarray | None = None
    fix_enh_m: np.ndarray | None = None
    station: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.5)
    repeat: bool = False


@dataclass
class FleetConfig:
    """Device settings of the twins (written to the devices file so the drivers match).

    Attributes
    ----------
    imu_type : RAWIMUSX IMU type (scale table). imu_rate_hz : None: from the IMU time steps.
    odometer : counter settings. noise_angle_rad, noise_dist_m : total-station noise.
    faults : fault settings applied to the devices in ``fault_devices`` (each twin gets its own
        seed, ``faults.seed + index``).
    link_dir : make stable symlinks ``link_dir/<device>`` (like ``/dev/serial/by-id``).
    """

    imu_type: int = 26
    imu_rate_hz: float | None = None
    odometer: encoder.OdometerConfig = field(default_factory=encoder.OdometerConfig)
    noise_angle_rad: float = 0.0
    noise_dist_m: float = 0.0
    faults: Faults = field(default_factory=Faults)
    fault_devices: tuple[str, ...] = DEVICES
    link_dir: str | None = None


def synthetic_feed(imu_rate_hz: float = 200.0, gauge_rate_hz: float = 50.0, speed_m_s: float = 1.0,
                   station=(0.0, 0.0, 0.0, 1.5), target=(10.0, 20.0, 0.5),
                   latitude_rad: float = math.pi / 4) -> FleetFeed:
    """A stationary, level IMU facing north (gravity and Earth rate), an odometer at constant
    speed, a gauge of 1.435 m +- 2 mm (10 s sine) and one prism; repeated endlessly."""
    from trolley import units

    n = int(SYNTHETIC_BLOCK_S * imu_rate_hz)
    t = np.arange(n) / imu_rate_hz
    om = units.EARTH_RATE_RAD_S
    # level and facing north: Earth rate (cos, 0, -sin) * Omega in FRD, specific force -g down
    w = np.tile([om * math.cos(latitude_rad), 0.0, -om * math.sin(latitude_rad)], (n, 1))
    f = np.tile([0.0, 0.0, -units.STANDARD_GRAVITY_M_S2], (n, 1))
    to = np.arange(int(SYNTHETIC_BLOCK_S * 1000)) / 1000.0
    tg = np.arange(int(SYNTHETIC_BLOCK_S * gauge_rate_hz)) / gauge_rate_hz
    return FleetFeed(t, w, f, to, speed_m_s * to, tg, 1.435 + 0.002 * np.sin(2 * np.pi * tg / 10.0),
                     np.zeros(1), np.atleast_2d(np.asarray(target, float)),
                     tuple(float(x) for x in station), repeat=True)


def station_beside(fix_enh_m: np.ndarray, instrument_height_m: float = 1.5,
                   offset_m: float = 5.0) -> tuple[float, float, float, float]:
    """A station setting beside the fixes: their centroid moved ``offset_m`` east and north,
    with the axis at the mean prism height."""
    c = np.mean(np.asarray(fix_enh_m, float), axis=0)
    return float(c[0] + offset_m), float(c[1] + offset_m), float(c[2] - instrument_height_m), instrument_height_m


def nominal_rate_hz(t_s: np.ndarray) -> float:
    """Data rate from the median time step, snapped to whole hertz when within 1e-6."""
    r = 1.0 / float(np.median(np.diff(np.asarray(t_s, float))))
    return float(round(r)) if abs(r - round(r)) <= 1e-6 * r else r


class Fleet:
    """The twins of a feed on their ptys (built at once; :meth:`start` lets them speak)."""

    def __init__(self, feed: FleetFeed, cfg: FleetConfig = FleetConfig(),
                 devices: tuple[str, ...] = DEVICES) -> None:
        from pathlib import Path

        from drivers.twins.gauge import GaugeTwin
        from drivers.twins.imu import ImuTwin
        from drivers.twins.odometer import OdometerTwin
        from drivers.twins.totalstation import TotalStationTwin

        self.feed, self.cfg = feed, cfg
        self.epoch = Epoch()
        self.twins: dict[str, PtyTwin] = {}
        unknown = set(devices) - set(DEVICES)
        if unknown:
            raise ValueError(f"unknown device(s) {sorted(unknown)}; known: {', '.join(DEVICES)}")
        starts = [a[0] for a in (feed.imu_t_s, feed.odo_t_s, feed.gauge_t_s) if a is not None and len(a)]
        self.t0_s = float(min(starts)) if starts else 0.0  # session time of the epoch
        link = (lambda name: Path(cfg.link_dir) / name) if cfg.link_dir else (lambda name: None)

        def faults(name: str) -> Faults | None:
            if name not in cfg.fault_devices:
                return None
            return replace(cfg.faults, seed=cfg.faults.seed + DEVICES.index(name))

        rt = dict(repeat=feed.repeat)
        if "imu" in devices and feed.imu_t_s is not None:
            self.imu_rate_hz = cfg.imu_rate_hz or nominal_rate_hz(feed.imu_t_s)
            self.twins["imu"] = ImuTwin(feed.imu_t_s, feed.imu_w_rad_s, feed.imu_f_m_s2, imu_type=cfg.imu_type,
                                        rate_hz=self.imu_rate_hz, faults=faults("imu"), link_path=link("imu"), **rt)
        if "odometer" in devices and feed.odo_t_s is not None:
            self.twins["odometer"] = OdometerTwin(feed.odo_t_s, feed.odo_distance_m, cfg.odometer, mode="time",
                                                  faults=faults("odometer"), link_path=link("odometer"), **rt)
        if "gauge" in devices and feed.gauge_t_s is not None:
            self.twins["gauge"] = GaugeTwin(feed.gauge_t_s, feed.gauge_m, faults=faults("gauge"),
                                            link_path=link("gauge"), **rt)
        if "totalstation" in devices and feed.fix_enh_m is not None:
            self._fix = 0
            self.twins["totalstation"] = TotalStationTwin(
                feed.station, feed.fix_enh_m[0], cfg.noise_angle_rad, cfg.noise_dist_m,
                faults=faults("totalstation"), link_path=link("totalstation"), seed=cfg.faults.seed)
        firsts = {"imu": feed.imu_t_s, "odometer": feed.odo_t_s, "gauge": feed.gauge_t_s}
        for name, tw in self.twins.items():
            tw.epoch = self.epoch
            if name in firsts:
                tw.epoch_offset_s = float(firsts[name][0]) - self.t0_s

    @property
    def ports(self) -> dict[str, str]:
        """device -> path the application opens."""
        return {name: tw.port for name, tw in self.twins.items()}

    def ports_json(self) -> dict:
        """The devices file of ``trolley survey start --devices`` for these twins: the ports
        plus the driver options that match them."""
        out: dict = dict(self.ports)
        if "imu" in self.twins:
            out.update(imu_type=self.cfg.imu_type, imu_rate_hz=self.imu_rate_hz, imu_axes="x,y,z")
        if "odometer" in self.twins:
            o = asdict(self.cfg.odometer)
            out["odometer_config"] = {k: o[k] for k in ("ppr", "decode", "wheel_diameter_m", "scale", "bits")}
        return out

    def start(self) -> "Fleet":
        """Let every twin speak once the application has opened its port (no time limit)."""
        for tw in self.twins.values():
            tw.start(wait_client_s=math.inf)
        return self

    def tick(self, now: float) -> None:
        """Aim the total station at the fix whose time has come (call it now and then)."""
        ts = self.twins.get("totalstation")
        f = self.feed
        if ts is None or f.fix_t_s is None or f.fix_enh_m.shape[0] < 2 or self.epoch.value is None:
            return
        t = now - self.epoch.value + self.t0_s
        k = max(int(np.searchsorted(f.fix_t_s, t, side="right")) - 1, 0)
        if k != self._fix:
            self._fix = k
            ts.set_target(f.fix_enh_m[k])

    def stop(self) -> None:
        """Stop every twin and close its pty (and stable link)."""
        for tw in self.twins.values():
            tw.stop()
