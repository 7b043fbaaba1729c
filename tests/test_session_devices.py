"""A session on "real" devices (``--devices``): the twins started on their own, as instruments would
be, with no simulation clock. Checks the device time bases (IMU GPS time and gauge milliseconds
mapped on the host clock, odometer replies timed by arrival), the station setup with the crew
aiming the telescope, and a fix."""
from __future__ import annotations

import json
import time

import numpy as np
import pytest
from rich.console import Console

from session_project import make_project


def _setup_points(tmp_path, n=6):
    """The CPIII points a first setup on real devices measures, in its order (nearest to the start
    of the design), which the crew aims at."""
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.store import ProjectStore
    from trolley.landxml import parse_landxml

    with ProjectStore.open(tmp_path / "t1") as st:
        fs = FieldSession(st, "probe", SessionConfig(setup_points=n))
        fs._design = parse_landxml(st.alignment().landxml_text)
        pts = fs._setup_points()
        start = fs._design.evaluate(np.array([fs._design.start_chainage_m]))
        # nearest to the start of the design, not the first points of the file
        d = np.hypot([p.e_m - start.E_m[0] for p in st.cpiii_points()], [p.n_m - start.N_m[0] for p in st.cpiii_points()])
        assert sorted(p.point_id for p in pts) == sorted(st.cpiii_points()[i].point_id for i in np.argsort(d)[:n])
        return pts


def _twins(tmp_path, pts, station, prism, seconds=12.0, t0=0.0, seen=None, noise=True, constants=(0.0, 0.0),
           instrument_constant_m=0.0):
    """IMU, odometer, gauge and a crew-aimed total station, each started on its own like an instrument.

    ``seen`` maps a grid point to where the instrument sees it (ground distances, refraction); the
    default is the point itself. ``noise=False``: readings without noise. ``constants``: Leica
    constants (m) of the physical CPIII prisms and trolley prism; ``instrument_constant_m``: the
    instrument's prism constant before the session sets it."""
    from drivers import geocom as gc
    from drivers.twins.gauge import GaugeTwin
    from drivers.twins.imu import ImuTwin
    from drivers.twins.odometer import OdometerTwin
    from drivers.twins.totalstation import TotalStationTwin

    rate = 200.0
    t = t0 + np.arange(1, int(seconds * rate) + 1) / rate
    w = np.tile([0.0, 0.0, -3e-5], (t.size, 1))
    f = np.tile([0.0, 0.0, -9.79], (t.size, 1))
    imu = ImuTwin(t, w, f, imu_type=26, sow0=100000.0 + t0, link_path=tmp_path / "imu")
    to = np.arange(0, int(seconds * 100)) / 100.0
    odo = OdometerTwin(to, np.zeros_like(to), mode="time", link_path=tmp_path / "odo")
    tg = np.arange(1, int(seconds * 10) + 1) / 10.0
    gauge = GaugeTwin(tg, np.full(tg.size, 1.4352), link_path=tmp_path / "gauge")
    seen = seen or (lambda x: np.asarray(x, dtype=float))
    targets = [tuple(seen([p.e_m, p.n_m, p.h_m])) for p in pts]
    prism_seen = tuple(seen(prism))

    class CrewAimedStation(TotalStationTwin):
        """The crew aims at the next CPIII point for each setup pointing, then at the trolley's prism."""

        def handle(self, req):
            if req.rpc == gc.AUT_FINEADJUST:
                self.target_constant_m = constants[0] if targets else constants[1]
                self.target = targets.pop(0) if targets else prism_seen
            return super().handle(req)

    ts = CrewAimedStation(station=(*station, 0.0), link_path=tmp_path / "ts", noise_angle_rad=2e-6 if noise else 0.0,
                          noise_dist_m=3e-4 if noise else 0.0, seed=3, prism_corr_m=instrument_constant_m)
    return imu, odo, gauge, ts


def test_session_on_devices_given_by_ports(tmp_path):
    from survey.commands.survey import read_devices
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore

    make_project(tmp_path, static_s="2.0")
    pts = _setup_points(tmp_path)
    rate = 200.0
    station = np.array([pts[0].e_m + 10.0, pts[0].n_m + 5.0, pts[0].h_m + 1.5])
    prism = station + np.array([3.0, 12.0, -0.9])
    imu, odo, gauge, ts = _twins(tmp_path, pts, station, prism)
    (tmp_path / "ports.json").write_text(json.dumps({"imu": str(tmp_path / "imu"), "odometer": str(tmp_path / "odo"),
                                                     "gauge": str(tmp_path / "gauge"),
                                                     "totalstation": str(tmp_path / "ts"), "imu_type": 26}))
    ports, options = read_devices(tmp_path / "ports.json")
    for twin in (imu, odo, gauge, ts):
        twin.start(wait_client_s=20.0)
    console = Console(stderr=True, record=True, width=150)
    try:
        with ProjectStore.open(tmp_path / "t1") as st:
            fs = FieldSession(st, "real", SessionConfig(script=parse_script("wait 3\nfix\nend\n"), out_dir=None,
                                                        setup_points=6),
                              ports=ports, device_options=options, console=console)
            t0 = time.monotonic()
            fs.run()
            wall = time.monotonic() - t0
            sid = fs.rec.session_id
            it, iw, _ = st.imu_arrays(sid)
            ot, od = st.odometer_arrays(sid)
            gt, gm = st.gauge_arrays(sid)
            fixes = st.fixes(sid)
            setup = st.station_setups(sid)[0]
    finally:
        for twin in (imu, odo, gauge, ts):
            twin.stop()
    # IMU: device time on the host clock; frames 5 ms apart, none lost, within the session's wall time
    assert it.size > 200 and np.allclose(np.diff(it), 1 / rate, atol=1e-9)
    assert -0.5 < it[0] < wall and it[-1] < wall + 0.5
    assert np.allclose(iw[:, 2], -3e-5, atol=1e-9)
    # odometer: reply arrival times, polled at 100 Hz
    assert ot.size > 100 and np.all(np.diff(ot) > 0) and np.all(od == 0.0)
    assert 0.005 < np.median(np.diff(ot)) < 0.02
    # gauge: its millisecond clock, 100 ms apart
    assert np.allclose(np.diff(gt), 0.1, atol=1e-9) and np.allclose(gm, 1.4352, atol=1e-5)
    # the free station from the crew's pointings, and the fix of the prism in grid coordinates
    assert np.max(np.abs(setup.station_enh_m - station)) < 0.002 and setup.sigma0 < 3.0
    assert len(fixes) == 1 and np.max(np.abs(np.array([fixes[0].e_m, fixes[0].n_m, fixes[0].h_m]) - prism)) < 0.003


def test_a_fix_on_real_devices_follows_the_setups_grid_scale_and_curvature(tmp_path):
    """The fix is computed with the polar model of the station setup: the project's grid scale
    (here 1.00004 without a CRS) and Earth curvature and refraction. The instrument sees the prism
    250 m away at the ground distance (grid / 1.00004) and lowered by (1 - 0.13) hd^2 / 2R (4.3 mm);
    its own coordinates (TMC_GetCoordinate) hold neither. The fix must be the prism's grid point.

    The CPIII carry mini prisms (+17.5 mm), the trolley a 360° prism (+23.1 mm), and the instrument
    starts at +34.4 mm (tape): the session sets each constant before its prism is measured; the
    CPIII's constant left for the trolley prism puts the fix 5.6 mm short, the instrument's own 11.3 mm
    long, and the station is off by millimetres unless the CPIII constant is set."""
    import dataclasses

    from survey.commands.survey import read_devices
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore
    from trolley.resection import PolarModel

    k = 1.00004
    make_project(tmp_path, static_s="2.0")
    with ProjectStore.open(tmp_path / "t1") as st:
        st.set_settings(dataclasses.replace(st.settings(), polar_model=PolarModel(grid_scale=k),
                                            cpiii_prism_constant_m=0.0175, trolley_prism_constant_m=0.0231))
        drop = st.settings().polar_model.height_drop_per_m2
    pts = _setup_points(tmp_path)
    station = np.array([pts[0].e_m + 10.0, pts[0].n_m + 5.0, pts[0].h_m + 1.5])
    prism = station + np.array([125.0, 216.5, -0.9])  # 250 m away

    def seen(x):
        d = np.asarray(x, dtype=float) - station
        hd = np.hypot(d[0], d[1]) / k
        return station + np.array([d[0] / k, d[1] / k, d[2] - drop * hd**2])

    twins = _twins(tmp_path, pts, station, prism, seen=seen, noise=False, constants=(0.0175, 0.0231),
                   instrument_constant_m=0.0344)
    (tmp_path / "ports.json").write_text(json.dumps({"imu": str(tmp_path / "imu"), "odometer": str(tmp_path / "odo"),
                                                     "gauge": str(tmp_path / "gauge"),
                                                     "totalstation": str(tmp_path / "ts"), "imu_type": 26}))
    ports, options = read_devices(tmp_path / "ports.json")
    for twin in twins:
        twin.start(wait_client_s=20.0)
    try:
        with ProjectStore.open(tmp_path / "t1") as st:
            fs = FieldSession(st, "real", SessionConfig(script=parse_script("wait 3\nfix\nend\n"), out_dir=None,
                                                        setup_points=6),
                              ports=ports, device_options=options, console=Console(stderr=True, width=150))
            fs.run()
            fixes = st.fixes(fs.rec.session_id)
            setup = st.station_setups(fs.rec.session_id)[0]
            switches = [json.loads(e.detail) for e in st.events(fs.rec.session_id) if e.kind == "prism_constant"]
    finally:
        for twin in twins:
            twin.stop()
    # one switch to the CPIII prisms before the setup, one to the trolley prism before the fix
    assert switches == [{"prism": "cpiii", "constant_mm": pytest.approx(17.5)},
                        {"prism": "trolley", "constant_mm": pytest.approx(23.1)}]
    assert sum(r.rpc == 2024 for r in twins[3].requests) == 2
    assert np.max(np.abs(setup.station_enh_m - station)) < 1e-6
    assert len(fixes) == 1
    # from the instrument's coordinates the fix was 250 m x 4e-5 = 10 mm short horizontally (E -5.0,
    # N -8.7 mm) and 4.3 mm low (rtol 0: the default 1e-7 of 3.1e6 m would be 0.3 m)
    np.testing.assert_allclose([fixes[0].e_m, fixes[0].n_m, fixes[0].h_m], prism, rtol=0, atol=1e-6)


def test_resume_after_a_host_restart_starts_a_new_time_segment(tmp_path):
    """A power loss reboots the host: its monotonic clock starts again from a small value, so the
    stored ``host_t0`` means nothing any more. The resumed session must go on after the last
    stored sample (a new time segment, the gap recorded), and store every new odometer reply."""
    from survey.commands.survey import read_devices
    from survey.session.acquisition import TimeBase
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore, SessionEvent

    make_project(tmp_path, static_s="2.0")
    pts = _setup_points(tmp_path)
    station = np.array([pts[0].e_m + 10.0, pts[0].n_m + 5.0, pts[0].h_m + 1.5])
    prism = station + np.array([3.0, 12.0, -0.9])
    (tmp_path / "ports.json").write_text(json.dumps({"imu": str(tmp_path / "imu"), "odometer": str(tmp_path / "odo"),
                                                     "gauge": str(tmp_path / "gauge"),
                                                     "totalstation": str(tmp_path / "ts"), "imu_type": 26}))
    ports, options = read_devices(tmp_path / "ports.json")
    console = Console(stderr=True, record=True, width=150)

    def devices(**kw):
        twins = _twins(tmp_path, pts, station, prism, **kw)
        for twin in twins:
            twin.start(wait_client_s=20.0)
        return twins

    twins = devices()
    try:
        with ProjectStore.open(tmp_path / "t1") as st:
            fs = FieldSession(st, "r", SessionConfig(script=parse_script("wait 3\nfix\n"), out_dir=None,
                                                     setup_points=6), ports=ports, device_options=options,
                              console=console)
            fs.open_session()
            fs.start_devices()
            fs.station_setup()
            fs.loop()
            fs._shutdown()  # the power goes: no end of session
            sid = fs.rec.session_id
            last = {k: float(a[0][-1]) for k, a in (("imu", st.imu_arrays(sid)), ("odo", st.odometer_arrays(sid)),
                                                    ("gauge", st.gauge_arrays(sid)))}
            n_odo = st.odometer_arrays(sid)[0].size
            # the host restarts: its monotonic clock now reads 1e6 s less than in the first run
            clock = [json.loads(e.detail) for e in st.events(sid) if e.kind == "clock"][-1]
            assert clock["wall_t0"] is not None
            st.add_event(sid, SessionEvent(0.0, "clock", json.dumps({**clock, "host_t0": clock["host_t0"] + 1e6})))
    finally:
        for twin in twins:
            twin.stop()
    t_down = time.monotonic()
    twins = devices(t0=500.0)  # the devices restarted too: the IMU's GPS time and the gauge's clock moved on
    try:
        with ProjectStore.open(tmp_path / "t1") as st:
            # the same script goes on: its step 3 ("stop") stands for the first run's end of script
            fs = FieldSession(st, "r", SessionConfig(script=parse_script("wait 3\nfix\nstop\nwait 2\nfix\nend\n"),
                                                     out_dir=None),
                              ports=ports, device_options=options, console=console, resume=True)
            fs.run()
            events = st.events(sid)
            it, _, _ = st.imu_arrays(sid)
            ot, _ = st.odometer_arrays(sid)
            gt, _ = st.gauge_arrays(sid)
            fixes = st.fixes(sid)
    finally:
        for twin in twins:
            twin.stop()
    gaps = [json.loads(e.detail) for e in events if e.kind == "time_gap"]
    assert len(gaps) == 1
    gap = gaps[0]
    assert gap["last_stored_s"] == max(last.values()) and gap["monotonic_s"] < -1e5
    # the wall clock went on: the new segment starts where the wall clock says, after the old data
    # the wall clock says less than the minimum gap since the last data (a quick restart): 1 s after it
    assert gap["wall_s"] < gap["last_stored_s"] + 1.0 + (time.monotonic() - t_down)
    assert gap["resumed_at_s"] == max(gap["last_stored_s"] + 1.0, gap["wall_s"])
    for t, old, rate in ((it, last["imu"], 200), (ot, last["odo"], 100), (gt, last["gauge"], 10)):
        assert np.all(np.diff(t) > 0)  # one time line, no sample before an older one
        new = t[t > old]
        assert new.size > 1.5 * rate and new[0] > gap["resumed_at_s"] - 0.5  # the 2 s waited, and more
    assert ot.size - n_odo == fs.acq.samples["odometer"] and not fs.acq.dropped  # no reply dropped
    assert len(fixes) == 2 and fixes[1].t_s > gap["resumed_at_s"]
    assert TimeBase.from_json(json.loads([e for e in events if e.kind == "clock"][-1].detail)).host_t0 < \
        clock["host_t0"] + 1e6 - 1e5  # the new base is stored
    assert "the host restarted since the last data" in " ".join(console.export_text().split())


def test_an_instrument_that_keeps_another_prism_constant_stops_the_session_before_the_prism_is_measured():
    """The read-back after TMC_SetPrismCorr is what the session trusts: an instrument that answers OK
    and keeps its constant (here the round prism's 0.0 while the trolley carries a 360° prism) stops
    the session with the instrument, the constant expected and the one read, before any fix."""
    from drivers import geocom as gc
    from drivers.totalstation import TotalStation
    from drivers.twins.totalstation import TotalStationTwin
    from survey.session.errors import SessionAbort
    from survey.session.stationsetup import StationSetupSteps
    from survey.store import ProjectSettings

    class KeepsItsConstant(TotalStationTwin):
        def handle(self, req):
            return (0, ()) if req.rpc == gc.TMC_SETPRISMCORR else super().handle(req)

    class Session(StationSetupSteps):
        settings = ProjectSettings(trolley_prism_constant_m=0.0231)

        def __init__(self, ts):
            self.ts, self.events, self.said = ts, [], []

        def _event(self, kind, detail=""):
            self.events.append((kind, json.loads(detail)))

        def say(self, text):
            self.said.append(text)

    twin = KeepsItsConstant((0.0, 0.0, 0.0, 0.0), (10.0, 10.0, 0.0))
    ts = TotalStation(twin.port, timeout_s=2.0, long_timeout_s=2.0)
    ts.link.open()
    twin.start()
    try:
        ts.connect()
        session = Session(ts)
        session.use_prism("cpiii")  # 0.0 asked, 0.0 held: fine
        session.use_prism("cpiii")  # nothing sent again
        with pytest.raises(SessionAbort) as stopped:
            session.use_prism("trolley")
    finally:
        ts.close()
        twin.stop()
    assert str(stopped.value) == (f"total station {twin.port}: prism constant +0.00 mm on the instrument, +23.10 "
                                  "mm expected (read back after TMC_SetPrismCorr), for the trolley prism")
    assert "+23.1 mm by hand" in stopped.value.hint and "trolley_prism_constant_mm" in stopped.value.hint
    assert session.events == [("prism_constant", {"prism": "cpiii", "constant_mm": 0.0}),
                              ("prism_constant_mismatch", {"prism": "trolley", "expected_mm": pytest.approx(23.1),
                                                           "read_mm": 0.0})]
    assert session.said == ["total station: prism constant +0.0 mm for the CPIII prisms (set and read back)"]
    assert sum(r.rpc == gc.TMC_SETPRISMCORR for r in twin.requests) == 2


def test_the_devices_open_at_the_drivers_line_speeds_or_the_devices_files(tmp_path):
    """A session's odometer and gauge opened at 9600 baud, though the counter module and the gauge
    sensor speak 115200 (their drivers' and `devices record`'s default) and the devices file could
    not say otherwise: on real ports nothing readable arrived. The speed set on a pty is the slave's
    termios, which its master reads."""
    import os
    import pty
    import termios

    from survey.commands.survey import read_devices
    from survey.session.acquisition import Acquisition, TimeBase

    class Sink:
        def append(self, *a):
            pass

    fds, ports = [], {}
    for name in ("imu", "odometer", "gauge", "totalstation"):
        m, s = pty.openpty()
        fds += [m, s]
        ports[name] = os.ttyname(s)
    speed = {getattr(termios, f"B{b}"): b for b in (9600, 19200, 38400, 115200, 230400, 460800)}
    try:
        for given, want in (({}, {"imu": 460800, "odometer": 115200, "gauge": 115200}),
                            ({"imu_baud": 230400, "odometer_baud": 38400, "gauge_baud": 19200},
                             {"imu": 230400, "odometer": 38400, "gauge": 19200})):
            f = tmp_path / "ports.json"
            f.write_text(json.dumps({**ports, **given}))
            p, options = read_devices(f)
            bauds = {k[:-5]: v for k, v in options.items() if k.endswith("_baud")}
            acq = Acquisition({k: v for k, v in p.items() if k != "totalstation"}, Sink(), TimeBase(), bauds=bauds)
            acq.open(2.0)
            try:
                for name, link in acq.links.items():
                    master = fds[2 * list(ports).index(name)]
                    assert speed[termios.tcgetattr(master)[4]] == want[name], name
            finally:
                for link in acq.links.values():
                    link.stop()
    finally:
        for fd in fds:
            os.close(fd)


def test_a_gauge_sensor_that_restarts_its_clock_goes_on_in_time_order():
    """A bus-powered gauge sensor unplugged and plugged in again restarts its millisecond clock at 0.
    Its readings were stored on the old clock's mapping, up to its whole uptime in the past (here
    500 s before the session started), out of time order. So were they after a resume if it
    restarted while the session was down. A clock that goes on over an unplug, or wraps at 2^32 ms,
    keeps its mapping."""
    from drivers.gauge import MS_MODULO, GaugeRecord
    from survey.session.acquisition import Acquisition, TimeBase

    class Sink:
        def append(self, *a):
            pass

        def append_records(self, table, recs):
            pass

    def lines(t_host, ms0, n):  # 10 Hz, read 10 ms after each line
        return [GaugeRecord(t_host + 0.1 * k + 0.01, k, (ms0 + 100 * k) % MS_MODULO, 1.435, 0) for k in range(n)]

    tb = TimeBase(host_t0=1000.0, wall_t0=0.0)
    acq = Acquisition({}, Sink(), tb)
    acq.samples["gauge"] = 0
    acq._gauge(lines(1000.0, MS_MODULO - 2000, 50))   # its clock wraps at 2 s
    acq._gauge(lines(1008.0, 6000, 10))               # unplugged 3 s, its clock ran on
    acq._gauge(lines(1012.0, 0, 10))                  # power-cycled: its clock restarted
    t = acq.buffers.array("gauge")[:, 0]
    np.testing.assert_allclose(t[:50], 0.01 + 0.1 * np.arange(50), atol=1e-9)
    np.testing.assert_allclose(t[50:60], 8.01 + 0.1 * np.arange(10), atol=1e-9)
    np.testing.assert_allclose(t[60:], 12.01 + 0.1 * np.arange(10), atol=1e-9)
    # a resumed session (the same host run): its stored time base, and the sensor restarted meanwhile
    resumed = Acquisition({}, Sink(), TimeBase(host_t0=1000.0, wall_t0=0.0, gauge_origin_s=tb.gauge_origin_s))
    resumed.samples["gauge"] = 0
    resumed.buffers.add("gauge", acq.buffers.array("gauge"))
    resumed._gauge(lines(1030.0, 0, 10))
    np.testing.assert_allclose(resumed.buffers.array("gauge")[70:, 0], 30.01 + 0.1 * np.arange(10), atol=1e-9)
    assert not acq.write_error and not resumed.write_error


def test_an_odometer_counter_restarted_by_an_unplug_carries_the_distance_on():
    """A bus-powered counter module unplugged and plugged in again restarts at 0; its driver starts
    a new segment (drivers/encoder.py). The session computed the distance from the first count
    without segments, so the distance jumped back by the whole count (here 12 m)."""
    from drivers.encoder import EncoderRecord, OdometerConfig
    from survey.session.acquisition import Acquisition, TimeBase

    class Sink:
        def append(self, *a):
            pass

        def append_records(self, table, recs):
            pass

    cfg = OdometerConfig()
    per_m = 1.0 / cfg.metres_per_count
    acq = Acquisition({}, Sink(), TimeBase(host_t0=1000.0, wall_t0=0.0), odometer=cfg)
    acq.samples["odometer"] = 0
    c0 = 5000
    acq._odometer([EncoderRecord(1000.0 + 0.01 * k, c0 + round(k * 0.01 * per_m), 0, 0) for k in range(1, 1201)])
    # unplugged at 12 m, power-cycled: the counter starts again at 0, the trolley moving on at 1 m/s
    acq._odometer([EncoderRecord(1015.0 + 0.01 * k, round(k * 0.01 * per_m), 0, 1) for k in range(100)])
    d = acq.buffers.array("odo")[:, 1]
    assert abs(d[1199] - 11.99) < 1e-3  # from the first reply
    np.testing.assert_allclose(d[1200:], d[1199] + 0.01 * np.arange(100), atol=1e-3)
