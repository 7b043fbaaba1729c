"""Total-station twin: a GeoCOM server with a station setup and a prism it is aimed at.

Geometry (what a real instrument computes): the instrument physically stands with its trunnion
axis at ``position`` (E, N, H of the axis point, fixed when the twin is made); the prism is at
(E, N, H). TMC_SetStation changes only the station *coordinates* the instrument uses to compute
TMC_GetCoordinate (E0, N0, H0, Hi), never where it physically stands. Azimuth ``az = atan2(dE, dN)``; the Hz reading is ``az - orientation``
(``TMC_SetOrientation`` sets the orientation so that the current direction reads the given
Hz); zenith angle ``V = atan2(horizontal distance, dH)``; slope distance is the 3-D distance.
Coordinates returned by TMC_GetCoordinate are computed back from the (noisy) readings and the
station: ``E = E0 + SD sin V sin Hz``, ``N = N0 + SD sin V cos Hz``,
``H = H0 + Hi + SD cos V - reflector height``.

Prism constant (Leica's convention, :data:`drivers.geocom.LEICA_PRISM_CONSTANT_M`): the prism the
twin is aimed at has its own additive constant ``target_constant_m`` (round 0.0, 360° +23.1 mm);
the instrument holds a configured correction ``prism_corr_m`` (TMC_SetPrismCorr / TMC_GetPrismCorr,
or the constant of the type BAP_SetPrismType selects, which overwrites it), and adds it to what its
EDM measured. The EDM alone reads the prism's reference point ``target_constant_m`` short (a 360°
prism's reflection lies 23.1 mm less far behind it than the round prism's, for which the EDM is
calibrated), so every slope distance it reports (TMC_GetSimpleMea, BAP_MeasDistanceAngle, and the
coordinates of TMC_GetCoordinate computed from it) is
``geometric distance + prism_corr_m - target_constant_m``: right when the instrument is set to the
prism it is aimed at, off by the difference otherwise.
"""
from __future__ import annotations

import math
import threading
import time
from collections import deque

import numpy as np

from drivers import geocom as gc
from drivers.twins.base import Faults, PtyTwin


class TotalStationTwin(PtyTwin):
    """A GeoCOM instrument on a pty.

    Parameters
    ----------
    station : (E0, N0, H0, instrument height) where the instrument physically stands; also its
        initial TMC station setting.
    target : (E, N, H) of the prism it is aimed at, or None (no prism: ATR finds nothing).
    target_constant_m : Leica additive constant of that prism (0.0 round, 0.0231 for a 360°).
    prism_corr_m : the instrument's configured prism correction at power-on (Leica's factory
        setting is the round prism, 0.0).
    noise_angle_rad, noise_dist_m : 1-sigma noise of angle and distance readings.
    sw_version : (release, version, subversion) for COM_GetSWVersion.
    atr_time_s, edm_time_s : how long ATR pointing (FineAdjust, positioning) and a distance
        measurement take before the reply (real instruments: about 1-5 s and 1-3 s).
    faults : byte faults on replies plus ``delay_rate``/``missing_rate`` per reply.
    seed : noise seed.
    echo_trid : answer with the transaction id (``%R1P,0,<trid>:``); False: the short form
        ``%R1P,0:`` the manual's framing also allows (requests without CRC only).

    Attributes
    ----------
    requests : every decoded request, in order.
    missing, delayed : indices into ``requests`` of the replies the random faults left out
        or sent ``delay_s`` late.
    """

    def __init__(self, station=(0.0, 0.0, 0.0, 0.0), target=None, noise_angle_rad: float = 0.0,
                 noise_dist_m: float = 0.0, sw_version=(1, 50, 0), faults: Faults | None = None,
                 link_path=None, seed: int = 0, atr_time_s: float = 0.0, edm_time_s: float = 0.0,
                 echo_trid: bool = True, target_constant_m: float = 0.0, prism_corr_m: float = 0.0) -> None:
        self.echo_trid = echo_trid
        self.missing: list[int] = []
        self.delayed: list[int] = []
        self.atr_time_s = atr_time_s
        self.edm_time_s = edm_time_s
        self.station = tuple(float(x) for x in station)
        e0, n0, h0, hi = self.station
        self.position = (e0, n0, h0 + hi)  # physical axis point; TMC_SetStation does not move it
        self.target = None if target is None else tuple(float(x) for x in target)
        self.target_constant_m = float(target_constant_m)
        self.prism_corr_m = float(prism_corr_m)
        self.noise_angle_rad = noise_angle_rad
        self.noise_dist_m = noise_dist_m
        self.sw_version = tuple(sw_version)
        self.orientation = 0.0
        self.reflector_height = 0.0
        self.pointing = (0.0, math.pi / 2)  # (azimuth, zenith) of the telescope
        self.atr_locked = False
        self.distance: tuple[float, float, float] | None = None  # measured (Hz, V, SD)
        self.requests: list[gc.Request] = []
        self._scripted_rc: deque = deque()
        self._drop_next = 0
        self._delay_next: deque = deque()
        self._lock = threading.Lock()
        self._rng = np.random.default_rng(seed)
        super().__init__(faults, link_path)

    # ------------------------------------------------------------------ settable state
    def set_target(self, target, constant_m: float = 0.0) -> None:
        """Aim at a prism at (E, N, H) whose Leica additive constant is ``constant_m``, or None for
        no prism."""
        with self._lock:
            self.target = None if target is None else tuple(float(x) for x in target)
            self.target_constant_m = float(constant_m)
            self.atr_locked = False
            self.distance = None

    def seed_noise(self, seed) -> None:
        """Restart the reading noise from ``seed`` (an int or a sequence of ints): readings that
        depend on what is measured, not on how many readings came before."""
        with self._lock:
            self._rng = np.random.default_rng(seed)

    def inject_rc(self, rc: int, rpc: int | None = None, times: int = 1) -> None:
        """Answer the next ``times`` requests (of ``rpc``, or any) with return code ``rc``."""
        with self._lock:
            for _ in range(times):
                self._scripted_rc.append((rpc, int(rc)))

    def drop_replies(self, n: int) -> None:
        """Do not answer the next ``n`` requests."""
        with self._lock:
            self._drop_next += n

    def delay_replies(self, n: int, seconds: float) -> None:
        """Answer the next ``n`` requests ``seconds`` late."""
        with self._lock:
            self._delay_next.extend([seconds] * n)

    # ------------------------------------------------------------------ geometry
    def true_polar(self) -> tuple[float, float, float]:
        """(azimuth, zenith, slope distance) from the trunnion axis to the prism."""
        ea, na, ha = self.position
        e, n, h = self.target
        de, dn, dh = e - ea, n - na, h - ha
        hd = math.hypot(de, dn)
        return math.atan2(de, dn) % (2 * math.pi), math.atan2(hd, dh), math.sqrt(hd * hd + dh * dh)

    def _read_angles(self) -> tuple[float, float]:
        az, v = self.pointing
        na = self.noise_angle_rad
        hz = (az - self.orientation + (self._rng.normal(0, na) if na else 0.0)) % (2 * math.pi)
        return hz, v + (self._rng.normal(0, na) if na else 0.0)

    def _coords(self) -> tuple[float, float, float]:
        hz, v, sd = self.distance
        e0, n0, h0, hi = self.station
        return (e0 + sd * math.sin(v) * math.sin(hz), n0 + sd * math.sin(v) * math.cos(hz),
                h0 + hi + sd * math.cos(v) - self.reflector_height)

    # ------------------------------------------------------------------ dispatch
    def handle(self, req: gc.Request) -> tuple[int, tuple]:
        """(rc, params) of the reply to ``req`` (state updated)."""
        rpc, p = req.rpc, req.params
        with self._lock:
            for i, (r_rpc, rc) in enumerate(self._scripted_rc):
                if r_rpc is None or r_rpc == rpc:
                    del self._scripted_rc[i]
                    return rc, ()
            if rpc == gc.COM_NULLPROC:
                return 0, ()
            if rpc == gc.COM_GETSWVERSION:
                return 0, self.sw_version
            if rpc == gc.COM_GETDOUBLEPRECISION:
                return 0, (15,)
            if rpc == gc.CSV_GETINSTRUMENTNAME:
                return 0, ("TS-TWIN",)
            if rpc in (gc.AUS_SETUSERATRSTATE, gc.AUS_SETUSERLOCKSTATE):
                return 0, ()
            if rpc == gc.TMC_SETPRISMCORR:
                if not p or not isinstance(p[0], (int, float)) or not math.isfinite(p[0]):
                    return 2, ()  # GRC_IVPARAM
                self.prism_corr_m = float(p[0])
                return 0, ()
            if rpc == gc.TMC_GETPRISMCORR:
                return 0, (self.prism_corr_m,)
            if rpc == gc.BAP_SETPRISMTYPE:
                # the type's constant overwrites TMC_SetPrismCorr's; a type whose constant this
                # software has no source for (user types, HDS target, ...) is refused, not guessed
                kind = p[0] if p else None
                if kind not in gc.LEICA_PRISM_CONSTANT_M:
                    return 2, ()  # GRC_IVPARAM
                self.prism_corr_m = gc.LEICA_PRISM_CONSTANT_M[kind]
                return 0, ()
            if rpc == gc.AUT_FINEADJUST:
                if self.target is None:
                    self.atr_locked = False
                    return 8710, ()
                az, v, _ = self.true_polar()
                self.pointing = (az, v)
                self.atr_locked = True
                return 0, ()
            if rpc == gc.AUT_MAKEPOSITIONING:
                self.pointing = ((float(p[0]) + self.orientation) % (2 * math.pi), float(p[1]))
                self.atr_locked = False
                if len(p) > 3 and int(p[3]) == 1:  # ATR target mode: fine-adjust at the end
                    if self.target is None:
                        return 8710, ()
                    az, v, _ = self.true_polar()
                    self.pointing = (az, v)
                    self.atr_locked = True
                return 0, ()
            if rpc == gc.AUT_LOCKIN:
                return (0, ()) if self.atr_locked else (8725, ())
            if rpc == gc.MOT_READLOCKSTATUS:
                return 0, (1 if self.atr_locked else 0,)
            if rpc == gc.TMC_DOMEASURE:
                cmd = int(p[0]) if p else 1
                if cmd in (gc.TMC_STOP, gc.TMC_CLEAR):
                    self.distance = None
                    return 0, ()
                self._measure_distance()
                return 0, ()
            if rpc in (gc.TMC_GETSIMPLEMEA, gc.TMC_GETCOORDINATE, gc.TMC_GETSIMPLECOORD):
                if self.distance == "error":
                    return 1294, ()
                if self.distance is None:
                    hz, v = self._read_angles()
                    return (1285, (hz, v, 0.0)) if rpc == gc.TMC_GETSIMPLEMEA else (1285, ())
                if rpc == gc.TMC_GETSIMPLEMEA:
                    return 0, self.distance
                e, n, h = self._coords()
                if rpc == gc.TMC_GETSIMPLECOORD:
                    return 0, (e, n, h)
                ms = int(time.monotonic() * 1000) % 2**31
                return 0, (e, n, h, ms, e, n, h, ms)
            if rpc == gc.BAP_MEASDISTANCEANGLE:
                mode = int(p[0]) if p else gc.BAP_DEF_DIST
                if mode == gc.BAP_NO_DIST:
                    hz, v = self._read_angles()
                    return 0, (hz, v, 0.0, mode)
                self._measure_distance()
                if self.distance == "error":
                    return 1294, ()
                return 0, (*self.distance, mode)
            if rpc == gc.TMC_GETANGLE:
                hz, v = self._read_angles()
                return 0, (hz, v, 1e-5, int(time.monotonic() * 1000) % 2**31, 0.0, 0.0, 1e-5,
                           int(time.monotonic() * 1000) % 2**31, 0)
            if rpc == gc.TMC_GETANGLE5:
                return 0, self._read_angles()
            if rpc == gc.TMC_SETSTATION:
                if self.distance is not None:
                    return 1293, ()
                self.station = tuple(float(x) for x in p[:4])
                return 0, ()
            if rpc == gc.TMC_GETSTATION:
                return 0, self.station
            if rpc == gc.TMC_SETORIENTATION:
                if self.distance is not None:
                    return 1293, ()
                self.orientation = (self.pointing[0] - float(p[0])) % (2 * math.pi)
                return 0, ()
            if rpc == gc.TMC_SETHEIGHT:
                self.reflector_height = float(p[0])
                return 0, ()
            if rpc == gc.TMC_GETHEIGHT:
                return 0, (self.reflector_height,)
            return -1, ()  # unknown RPC: COM_PROC_UNAVAIL at the communication layer

    def _measure_distance(self) -> None:
        if self.target is None or not self.atr_locked:
            self.distance = "error"
            return
        az, v, sd = self.true_polar()
        self.pointing = (az, v)
        hz, v_r = self._read_angles()
        nd = self.noise_dist_m
        sd += self.prism_corr_m - self.target_constant_m  # module docstring: Leica's convention
        self.distance = (hz, v_r, sd + (self._rng.normal(0, nd) if nd else 0.0))

    # ------------------------------------------------------------------ worker
    def serve(self) -> None:
        buf = bytearray()
        while not self.stopped:
            data = self.recv(0.05)
            if not data:
                continue
            buf += data
            while b"\n" in buf:
                i = buf.index(b"\n")
                line = bytes(buf[:i]).decode("latin-1").strip("\r\n")
                del buf[: i + 1]
                if not line:
                    continue  # leading LF: buffer clear
                j = line.rfind(gc.REQUEST_START)
                if j < 0:
                    continue
                self._answer(line[j:])

    def _answer(self, line: str) -> None:
        try:
            req = gc.decode_request(line)
        except (ValueError, IndexError):
            self.send(gc.encode_reply(3080, (), 0, com_rc=3080))
            return
        self.requests.append(req)
        trid = req.trid if req.trid is not None else 0
        if req.crc_present and not req.crc_ok:
            self.send(gc.encode_reply(3101, (), trid, com_rc=3101, with_crc=True))
            return
        rc, params = self.handle(req)
        work = (self.atr_time_s if req.rpc in (gc.AUT_FINEADJUST, gc.AUT_MAKEPOSITIONING) else
                self.edm_time_s if req.rpc in (gc.TMC_GETSIMPLEMEA, gc.TMC_GETCOORDINATE,
                                               gc.BAP_MEASDISTANCEANGLE) else 0.0)
        if work:
            time.sleep(work)  # one request at a time, like the instrument
        with self._lock:
            if self._drop_next > 0:
                self._drop_next -= 1
                return
            delay = self._delay_next.popleft() if self._delay_next else 0.0
        f = self.faults
        k = len(self.requests) - 1
        if f.missing_rate and self.injector.rng.random() < f.missing_rate:
            self.missing.append(k)
            return
        if f.delay_rate and self.injector.rng.random() < f.delay_rate:
            self.delayed.append(k)
            delay = max(delay, f.delay_s)
        if not self.echo_trid and not req.crc_present:
            trid = None
        if rc == -1:
            reply = gc.encode_reply(3081, (), trid, com_rc=3081, with_crc=req.crc_present)
        else:
            reply = gc.encode_reply(rc, params, trid, with_crc=req.crc_present)
        if delay:
            threading.Timer(delay, self.send, args=(reply,)).start()
        else:
            self.send(reply)
