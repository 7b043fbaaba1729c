"""``trolley devices probe`` and ``record`` against twins on ptys (in-process CLI)."""
from __future__ import annotations

import json
import termios

import numpy as np
import pytest
from typer.testing import CliRunner

from drivers import encoder, novatel
from drivers.replay import replay_imu
from drivers.stats import Stats
from drivers.twins.gauge import GaugeTwin
from drivers.twins.imu import ImuTwin
from drivers.twins.odometer import OdometerTwin
from drivers.twins.totalstation import TotalStationTwin
from survey.cli import app

runner = CliRunner()


def test_probe_json_ok_and_no_target():
    twin = TotalStationTwin((100.0, 200.0, 10.0, 1.6), (110.0, 230.0, 11.0)).start()
    try:
        r = runner.invoke(app, ["devices", "probe", "--totalstation", twin.port, "--baud", "19200", "--json"])
    finally:
        twin.stop()
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["ok"] and out["rc"] == 0
    assert (out["E_m"], out["N_m"], out["H_m"]) == pytest.approx((110.0, 230.0, 11.0), abs=1e-9)
    assert out["slope_m"] == pytest.approx(np.sqrt(10**2 + 30**2 + 0.6**2), abs=1e-9)
    twin = TotalStationTwin((100.0, 200.0, 10.0, 1.6), None).start()
    try:
        r = runner.invoke(app, ["devices", "probe", "--totalstation", twin.port, "--json"])
    finally:
        twin.stop()
    assert r.exit_code == 1
    out = json.loads(r.stdout)
    assert out == {"ok": False, "rc": 8710, "name": "GRC_AUT_NO_TARGET", "error": out["error"]}
    assert "No target" in out["error"] and "Traceback" not in r.output


def test_record_writes_session_files_raw_logs_and_stats(tmp_path):
    rate = 200.0
    n = int(6 * rate)
    t = np.arange(n) / rate
    w = np.tile([0.01, -0.02, 0.03], (n, 1))
    f = np.tile([0.1, 0.2, -9.8], (n, 1))
    cfg = encoder.OdometerConfig(ppr=500, decode=2, wheel_diameter_m=0.15, scale=1.002)
    imu = ImuTwin(t, w, f, imu_type=26, rate_hz=rate, axes="x,-y,-z").start(wait_client_s=30)
    odo = OdometerTwin(t, 0.8 * t, cfg, mode="time").start(wait_client_s=30)
    gg = GaugeTwin(t[::4], 1.435 + 0.001 * np.sin(t[::4])).start(wait_client_s=30)
    out = tmp_path / "rec"
    try:
        r = runner.invoke(app, ["devices", "record", "--imu", imu.port, "--odometer", odo.port, "--gauge", gg.port,
                                "--seconds", "1.5", "--out", str(out), "--imu-axes", "x,-y,-z",
                                "--odometer-ppr", "500", "--odometer-decode", "2", "--wheel-diameter-m", "0.15",
                                "--odometer-scale", "1.002"])
    finally:
        for tw in (imu, odo, gg):
            tw.stop()
    assert r.exit_code == 0, r.output
    imu_csv = np.genfromtxt(out / "imu.csv", delimiter=",", names=True)
    assert imu_csv.dtype.names == ("t_s", "wx_rad_s", "wy_rad_s", "wz_rad_s", "fx_m_s2", "fy_m_s2", "fz_m_s2")
    assert 150 < imu_csv.size < 400
    assert np.allclose(np.diff(imu_csv["t_s"]), 1 / rate, atol=1e-9)
    sc = novatel.imu_scale(26, rate)
    assert np.allclose(imu_csv["wy_rad_s"], -0.02, atol=sc.gyro * rate)
    assert np.allclose(imu_csv["fz_m_s2"], -9.8, atol=sc.accel * rate)
    odo_csv = np.genfromtxt(out / "odometer.csv", delimiter=",", names=True)
    assert odo_csv.dtype.names == ("t_s", "distance_m") and odo_csv.size > 50
    assert np.all(np.diff(odo_csv["distance_m"]) >= 0) and np.all(np.diff(odo_csv["t_s"]) > 0)
    speed = np.polyfit(odo_csv["t_s"], odo_csv["distance_m"], 1)[0]
    assert speed == pytest.approx(0.8 * 1.002, rel=0.1)  # twin speed x calibrated scale
    g_csv = np.genfromtxt(out / "gauge.csv", delimiter=",", names=True)
    assert g_csv.dtype.names == ("t_s", "gauge_m") and np.all(np.abs(g_csv["gauge_m"] - 1.435) <= 0.00101)
    stats = json.loads((out / "stats.json").read_text())
    assert set(stats) == {"imu", "odometer", "gauge"}
    for s in stats.values():
        assert s["bytes_in"] == s["bytes_ok"] + s["bytes_discarded"] + s["bytes_pending"]
    assert stats["imu"]["frames_ok"] == imu_csv.size and stats["imu"]["bad_checksum"] == 0
    frames, _ = replay_imu(out / "imu.rawlog")
    assert len(frames) == imu_csv.size


def test_record_missing_frames_counted_with_the_rate_inferred(tmp_path):
    # 400 Hz from an IMU type whose nominal rate is 200 Hz: gaps and scaling need the real rate
    rate = 400.0
    t = np.arange(500) / rate
    keep = np.setdiff1d(np.arange(500), np.r_[100, 200:203, 300:305])  # 3 gaps, 9 frames missing
    w, f = np.array([0.01, -0.02, 0.03]), np.array([0.1, 0.2, -9.8])
    imu = ImuTwin(t[keep], np.tile(w, (keep.size, 1)), np.tile(f, (keep.size, 1)), imu_type=26, rate_hz=rate,
                  realtime=False).start(wait_client_s=30)
    out = tmp_path / "rec [night 3]"     # printed literally, brackets and all (no rich markup)
    try:
        r = runner.invoke(app, ["devices", "record", "--imu", imu.port, "--seconds", "1.5", "--out", str(out),
                                "--imu-baud", "230400"])
        speed = termios.tcgetattr(imu.slave)[5]  # the line settings the driver left on the port
    finally:
        imu.stop()
    assert r.exit_code == 0, r.output
    assert f"into {out}" in " ".join(r.stderr.split()), r.stderr
    assert speed == termios.B230400
    st = json.loads((out / "stats.json").read_text())["imu"]
    assert st["frames_ok"] == keep.size
    assert st["extra"]["rate_hz"] == rate
    assert st["extra"]["time_gaps"] == 3 and st["extra"]["frames_missing"] == 9
    csv = np.genfromtxt(out / "imu.csv", delimiter=",", names=True)
    sc = novatel.imu_scale(26, rate)
    assert np.allclose(csv["wy_rad_s"], w[1], atol=sc.gyro * rate) and np.allclose(csv["fz_m_s2"], f[2], atol=sc.accel * rate)


def test_record_bad_axis_map_is_a_clear_error(tmp_path):
    r = runner.invoke(app, ["devices", "record", "--imu", "/dev/null", "--seconds", "1", "--out", str(tmp_path),
                            "--imu-axes", "x,x,z"])
    assert r.exit_code == 2 and "axis x used twice" in r.stderr and "Traceback" not in r.output


def test_simulate_one_device_prints_its_port_and_stops_after_seconds():
    import subprocess
    import sys
    import time

    from drivers import gauge
    from drivers.serialport import SerialLink
    from drivers.stats import Stats

    p = subprocess.Popen([sys.executable, "-m", "survey.cli", "devices", "simulate", "--device", "gauge",
                          "--seconds", "6", "--gauge-rate-hz", "50"], stdout=subprocess.PIPE, text=True)
    try:
        ports = json.loads(p.stdout.readline())
        assert set(ports) == {"gauge"}
        port = ports["gauge"]
        assert port.startswith("/dev/")
        stats = Stats()
        link = SerialLink(port, gauge.GaugeParser(stats), "gauge")
        link.start()
        recs = []
        deadline = time.monotonic() + 10.0
        while len(recs) < 10 and time.monotonic() < deadline:
            r = link.get(0.5)
            if r is not None:
                recs.append(r)
        link.stop()
        assert p.wait(15) == 0  # --seconds 6: ends by itself
    finally:
        if p.poll() is None:
            p.kill()
    assert len(recs) >= 10 and stats.bad_checksum == 0
    assert all(abs(r.gauge_m - 1.435) <= 0.00201 for r in recs)


def test_truthsim_session_through_twins_records_a_session_the_reader_accepts(tmp_path):
    """Whole chain: simulator arrays -> twins -> ptys -> drivers -> CSV -> survey session reader."""
    import shutil
    from pathlib import Path

    from survey.sessionio import read_session, write_session
    from trolley.landxml import parse_landxml
    from trolley.truthsim import SimulationConfig, simulate_survey

    demo = Path(__file__).resolve().parents[1] / "projects" / "demo" / "alignment.xml"
    sim = simulate_survey(parse_landxml(demo.read_text(encoding="utf-8")),
                          SimulationConfig(length_m=30.0, static_s=1.0, stop_s=1.0, fix_spacing_m=15.0,
                                           imu_rate_hz=200.0, seed=4))
    s = sim.session
    cfg = encoder.OdometerConfig()
    imu = ImuTwin(s.imu_t_s, s.imu_w_rad_s, s.imu_f_m_s2, imu_type=26, rate_hz=200.0, realtime=False).start(30)
    odo = OdometerTwin(s.odo_t_s, s.odo_distance_m, cfg, offset_counts=2**32 - 5000, mode="index").start(30)
    gg = GaugeTwin(s.gauge_t_s, s.gauge_m, realtime=False).start(30)
    rec = tmp_path / "rec"
    try:
        r = runner.invoke(app, ["devices", "record", "--imu", imu.port, "--odometer", odo.port, "--gauge", gg.port,
                                "--seconds", "1.5", "--out", str(rec)])
    finally:
        for tw in (imu, odo, gg):
            tw.stop()
    assert r.exit_code == 0, r.output
    write_session(tmp_path / "ref", s)
    for name in ("session.toml", "fixes.csv"):
        shutil.copy(tmp_path / "ref" / name, rec / name)
    # the fixes in the recording's time base (the reader refuses fixes outside the IMU log)
    import pandas as pd

    t0 = float(pd.read_csv(rec / "imu.csv", usecols=["t_s"], nrows=1)["t_s"].iloc[0])
    fixes = pd.read_csv(rec / "fixes.csv")
    fixes["t_s"] = t0 + 0.1 * np.arange(1, len(fixes) + 1)
    fixes.to_csv(rec / "fixes.csv", index=False)
    got = read_session(rec)
    sc = novatel.imu_scale(26, 200.0)
    assert got.imu_t_s.size == s.imu_t_s.size
    assert np.allclose(np.diff(got.imu_t_s), np.diff(s.imu_t_s), atol=1e-9)
    assert np.max(np.abs(got.imu_w_rad_s - s.imu_w_rad_s)) <= 0.5 * sc.gyro * 200.0 * 1.001
    assert np.max(np.abs(got.imu_f_m_s2 - s.imu_f_m_s2)) <= 0.5 * sc.accel * 200.0 * 1.001
    # the trolley stands still for the first second, so the first reading is distance 0 whichever
    # poll it answered; every reading is one of the simulator's distances (to one count)
    ref = s.odo_distance_m - s.odo_distance_m[0]
    assert got.odo_t_s.size > 50 and got.odo_distance_m[-1] > 0.0
    nearest = np.abs(got.odo_distance_m[:, None] - ref[None, : 4 * got.odo_t_s.size]).min(axis=1)
    assert np.all(nearest <= cfg.metres_per_count)
    assert np.allclose(got.gauge_m, s.gauge_m, atol=5.01e-6)


def test_record_refuses_a_counter_of_another_width_and_names_the_option(tmp_path):
    # the counter module is 24-bit (8-digit fields); the recording is set to the default 32 bits
    rate = 200.0
    t = np.arange(int(6 * rate)) / rate
    imu = ImuTwin(t, np.tile([0.0, 0.0, 0.0], (t.size, 1)), np.tile([0.0, 0.0, -9.8], (t.size, 1)),
                  imu_type=26, rate_hz=rate).start(wait_client_s=30)
    odo = OdometerTwin(t, 0.5 * t, encoder.OdometerConfig(bits=24), mode="time").start(wait_client_s=30)
    out = tmp_path / "rec"
    try:
        r = runner.invoke(app, ["devices", "record", "--imu", imu.port, "--odometer", odo.port,
                                "--seconds", "1.0", "--out", str(out)])
    finally:
        for tw in (imu, odo):
            tw.stop()
    assert r.exit_code == 2, r.output
    assert "24-bit counter" in r.output and "--odometer-bits 24" in r.output and "Traceback" not in r.output
    assert not (out / "odometer.csv").exists()


def test_encoder_parser_counts_replies_of_another_width():
    st = Stats()
    p = encoder.EncoderParser(st, encoder.OdometerConfig(bits=32))
    p.feed(encoder.format_read_reply(5, 0, bits=16) * 3 + encoder.format_read_reply(7, 0, bits=32) * 3, 0.0)
    assert st.extra["width_mismatch"] == 3 and st.extra["counter_bits_seen"] == 16
    err = encoder.width_mismatch_error(st, p.cfg, "/dev/ttyUSB2")
    assert isinstance(err, encoder.CounterWidthMismatch)
    assert "odometer on /dev/ttyUSB2: 3 counter replies have 5-digit counts" in str(err)
    assert "--odometer-bits 16" in str(err)
    assert encoder.width_mismatch_error(Stats(), p.cfg) is None
