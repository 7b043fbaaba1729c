"""A session on "real" devices (``--devices``): the twins started on their own, as instruments would
be, with no simulation clock. Checks the device time bases (IMU GPS time and gauge milliseconds
mapped on the host clock, odometer replies timed by arrival), the station setup with the crew
aiming the telescope, and a fix."""
from __future__ import annotations

import json
import time

import numpy as np
from rich.console import Console

from session_project import make_project


def test_session_on_devices_given_by_ports(tmp_path):
    from drivers import geocom as gc
    from drivers.twins.gauge import GaugeTwin
    from drivers.twins.imu import ImuTwin
    from drivers.twins.odometer import OdometerTwin
    from drivers.twins.totalstation import TotalStationTwin
    from survey.commands.survey import read_devices
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore

    make_project(tmp_path, static_s="2.0")
    with ProjectStore.open(tmp_path / "t1") as st:
        pts = st.cpiii_points()[:6]
    rate = 200.0
    t = np.arange(1, int(12 * rate) + 1) / rate
    w = np.tile([0.0, 0.0, -3e-5], (t.size, 1))
    f = np.tile([0.0, 0.0, -9.79], (t.size, 1))
    imu = ImuTwin(t, w, f, imu_type=26, link_path=tmp_path / "imu")
    to = np.arange(0, 1200) / 100.0
    odo = OdometerTwin(to, np.zeros_like(to), mode="time", link_path=tmp_path / "odo")
    tg = np.arange(1, 121) / 10.0
    gauge = GaugeTwin(tg, np.full(tg.size, 1.4352), link_path=tmp_path / "gauge")
    station = np.array([pts[0].e_m + 10.0, pts[0].n_m + 5.0, pts[0].h_m + 1.5])
    prism = station + np.array([3.0, 12.0, -0.9])
    targets = [(p.e_m, p.n_m, p.h_m) for p in pts]

    class CrewAimedStation(TotalStationTwin):
        """The crew aims at the next CPIII point for each setup pointing, then at the trolley's prism."""

        def handle(self, req):
            if req.rpc == gc.AUT_FINEADJUST:
                self.target = targets.pop(0) if targets else tuple(prism)
            return super().handle(req)

    ts = CrewAimedStation(station=(*station, 0.0), link_path=tmp_path / "ts", noise_angle_rad=2e-6,
                          noise_dist_m=3e-4, seed=3)
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
    assert np.max(np.abs(setup.station_enh_m - station)) < 0.002
    assert len(fixes) == 1 and np.max(np.abs(np.array([fixes[0].e_m, fixes[0].n_m, fixes[0].h_m]) - prism)) < 0.003
