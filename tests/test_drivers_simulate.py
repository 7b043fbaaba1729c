"""``trolley devices simulate``: all twins in a subprocess, driven through their ptys by the real
drivers; synthetic and session feeds; the devices file it writes is the one ``survey start`` reads."""
from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from drivers import encoder, novatel
from drivers.recorder import RecordConfig, record
from drivers.totalstation import TotalStation
from survey.commands.survey import read_devices
from trolley import units


def _start(args, out: Path):
    p = subprocess.Popen([sys.executable, "-m", "survey.cli", "devices", "simulate", "--out", str(out), *args],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60.0
    while not out.exists():
        if p.poll() is not None or time.monotonic() > deadline:
            p.kill()
            raise AssertionError(f"simulate did not write {out}: {p.communicate()}")
        time.sleep(0.05)
    return p, json.loads(out.read_text())


def _stop(p, sig):
    p.send_signal(sig)
    try:
        _, err = p.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        p.kill()
        raise
    return p.returncode, err


def _record(ports, seconds=2.0):
    ports_, opts = read_devices(ports)
    cfg = RecordConfig(imu_port=ports_["imu"], odometer_port=ports_["odometer"], gauge_port=ports_["gauge"],
                       seconds=seconds, odometer=encoder.OdometerConfig(**opts["odometer_config"]))
    return record(cfg), opts


def test_synthetic_twins_probe_record_sigint(tmp_path):
    out = tmp_path / "PORTS.json"
    p, ports = _start(["--corrupt-rate", "1e-3", "--fault-device", "imu", "--seed", "3"], out)
    try:
        assert set(ports) >= {"imu", "odometer", "gauge", "totalstation"}
        parsed, opts = read_devices(out)  # the reader of `survey start --devices`, unchanged
        assert parsed == {k: ports[k] for k in ("imu", "odometer", "gauge", "totalstation")}
        assert opts["imu_type"] == 26 and opts["imu_rate_hz"] == 200.0
        with TotalStation(ports["totalstation"]) as ts:
            ver = ts.sw_version()
            ts.fine_adjust()
            m = ts.measure()
        assert ver == (1, 50, 0)
        assert (m.E_m, m.N_m, m.H_m) == pytest.approx((10.0, 20.0, 0.5), abs=1e-9)
        assert m.slope_m == pytest.approx(math.sqrt(10**2 + 20**2 + 1.0**2), abs=1e-9)  # axis at H 1.5
        rec, _ = _record(out)
    finally:
        code, err = _stop(p, signal.SIGINT)
    assert code == 0 and "Traceback" not in err, err
    assert not out.exists()  # removed: the ports it named are gone
    # IMU: a level IMU facing north at 45 deg; corrupted frames fail their CRC, none is accepted
    n = rec.imu_t_s.size
    assert 300 <= n <= 500
    sc = novatel.imu_scale(26, 200.0)
    om, lat = units.EARTH_RATE_RAD_S, math.pi / 4
    assert np.allclose(rec.imu_w_rad_s, [om * math.cos(lat), 0.0, -om * math.sin(lat)], atol=0.5 * sc.gyro * 200 * 1.001)
    assert np.allclose(rec.imu_f_m_s2, [0.0, 0.0, -units.STANDARD_GRAVITY_M_S2], atol=0.5 * sc.accel * 200 * 1.001)
    st = rec.stats["imu"]
    assert st.bad_checksum > 0 and st.extra["rate_hz"] == 200.0
    assert st.extra["frames_missing"] >= st.bad_checksum  # every lost frame shows as a time gap
    # odometer at 1 m/s, gauge 1.435 m +- 2 mm
    speed = np.polyfit(rec.odo_t_s, rec.odo_distance_m, 1)[0]
    assert speed == pytest.approx(1.0, rel=0.05)
    assert rec.gauge_m.size > 50 and np.all(np.abs(rec.gauge_m - 1.435) <= 0.002 + 5e-6)


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    from survey.sessionio import write_session
    from trolley.landxml import parse_landxml
    from trolley.truthsim import SimulationConfig, simulate_survey

    demo = Path(__file__).resolve().parents[1] / "projects" / "demo" / "alignment.xml"
    sim = simulate_survey(parse_landxml(demo.read_text(encoding="utf-8")),
                          SimulationConfig(length_m=30.0, static_s=1.0, stop_s=1.0, fix_spacing_m=15.0,
                                           imu_rate_hz=200.0, seed=4))
    d = tmp_path_factory.mktemp("sess") / "raw"
    write_session(d, sim.session)
    return d


def test_session_feed_values_reach_the_drivers_sigterm(tmp_path, session_dir):
    from survey.sessionio import read_session

    s = read_session(session_dir)
    out = tmp_path / "PORTS.json"
    p, ports = _start(["--session-dir", str(session_dir)], out)
    try:
        rec, opts = _record(out, seconds=1.5)
        with TotalStation(ports["totalstation"]) as ts:
            ts.fine_adjust()
            m = ts.measure()
    finally:
        code, err = _stop(p, signal.SIGTERM)
    assert code == 0 and "Traceback" not in err, err
    assert not out.exists()
    # IMU: consecutive session rows, to the wire quantisation (half a count)
    sc = novatel.imu_scale(26, 200.0)
    w = rec.imu_w_rad_s
    n = w.shape[0]
    assert n > 200 and rec.stats["imu"].bad_checksum == 0 and rec.stats["imu"].extra["time_gaps"] == 0
    err0 = np.abs(s.imu_w_rad_s[: s.imu_t_s.size - n + 1, None, :] - w[None, :1, :]).max(axis=(1, 2))
    k0 = int(np.argmin(err0))
    assert np.max(np.abs(w - s.imu_w_rad_s[k0: k0 + n])) <= 0.5 * sc.gyro * 200 * 1.001
    assert np.max(np.abs(rec.imu_f_m_s2 - s.imu_f_m_s2[k0: k0 + n])) <= 0.5 * sc.accel * 200 * 1.001
    assert np.allclose(np.diff(rec.imu_t_s), np.diff(s.imu_t_s[k0: k0 + n]), atol=1e-9)
    # odometer: every reading is one of the session's distances (to one count), from its start
    cfg = encoder.OdometerConfig(**opts["odometer_config"])
    d = rec.odo_distance_m
    ref = s.odo_distance_m - s.odo_distance_m[0]
    assert d.size > 50 and np.all(np.abs(d[:, None] - ref[None, :]).min(axis=1) <= cfg.metres_per_count)
    # gauge: session values to the 0.01 mm of the line protocol
    g = rec.gauge_m
    assert g.size > 10 and np.all(np.abs(g[:, None] - s.gauge_m[None, :]).min(axis=1) <= 5.01e-6)
    # total station: aimed at one of the session's fixes (which one depends on the time)
    dist = np.abs(s.fixes.enh_m - [m.E_m, m.N_m, m.H_m]).max(axis=1)
    assert dist.min() <= 1e-9


def test_bad_session_is_a_clear_error(tmp_path):
    r = subprocess.run([sys.executable, "-m", "survey.cli", "devices", "simulate", "--session", str(tmp_path / "nope"),
                        "--out", str(tmp_path / "P.json")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "not a session folder" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "P.json").exists()
