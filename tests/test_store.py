"""Project store: schema, migrations, append-only raw rows, batch commits, row round trips (survey/store.py)."""
from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from dataclasses import replace

import numpy as np
import pytest

from survey import store as st
from survey.store import (
    ControlPoint,
    FixRecord,
    GaugeRecord,
    ImuRecord,
    NoteRecord,
    OdometerRecord,
    ProjectSettings,
    ProjectStore,
    RecordWriter,
    SessionEvent,
    SetupObservation,
    StationSetupRecord,
    StopRecord,
    StoreError,
    TrackResult,
)
from trolley.resection import PolarModel
from trolley.sensors import IMU_PRESETS
from trolley.session import Fixes, RawSession, SessionMeta, TrolleyGeometry


@pytest.fixture
def store(tmp_path):
    s = ProjectStore.create(tmp_path, "p1")
    yield s
    s.close()


def test_create_sets_pragmas_and_layout(tmp_path):
    s = ProjectStore.create(tmp_path, "line7")
    assert s.path == tmp_path / "line7" / "project.sqlite"
    c = s.connection
    assert c.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert c.execute("PRAGMA foreign_keys").fetchone()[0] == 1
    assert c.execute("PRAGMA application_id").fetchone()[0] == st.APPLICATION_ID
    assert s.info().schema_version == st.SCHEMA_VERSION == len(st.MIGRATIONS)
    assert s.info().name == "line7"
    s.close()
    with pytest.raises(StoreError, match="already exists"):
        ProjectStore.create(tmp_path, "line7")
    with pytest.raises(StoreError, match="no project"):
        ProjectStore.open_project(tmp_path, "nope")
    with ProjectStore.open_project(tmp_path, "line7") as again:
        assert again.info().name == "line7"


def test_foreign_keys_enforced(store):
    with pytest.raises(sqlite3.IntegrityError):
        store.add_note(999, NoteRecord(1.0, "no such session"))


def test_refuses_foreign_and_newer_files(tmp_path):
    other = tmp_path / "other.sqlite"
    sqlite3.connect(other).execute("CREATE TABLE x (a)").connection.close()
    with pytest.raises(StoreError, match="not a trolley-survey project"):
        ProjectStore.open(other)
    s = ProjectStore.create(tmp_path, "p")
    s.connection.execute(f"PRAGMA user_version = {st.SCHEMA_VERSION + 1}")
    s.close()
    with pytest.raises(StoreError, match="newer than this software"):
        ProjectStore.open(tmp_path / "p")


def test_a_store_on_a_read_only_medium_is_said_to_be_read_only(tmp_path, monkeypatch):
    # (as root a chmod does not stop writes; a write-protected card does: os.access says so)
    ProjectStore.create(tmp_path, "p").close()
    real = st.os.access
    monkeypatch.setattr(st.os, "access", lambda path, mode: False if mode == st.os.W_OK else real(path, mode))
    with pytest.raises(StoreError, match="the project store is read-only .* copy the project folder"):
        ProjectStore.open(tmp_path / "p")


def test_v1_database_is_migrated_on_open(tmp_path):
    path = tmp_path / "old" / st.STORE_FILE
    path.parent.mkdir()
    conn = st.connect(path)
    conn.execute(f"PRAGMA application_id = {st.APPLICATION_ID}")
    assert st.migrate(conn, target=1) == 1
    conn.execute("INSERT INTO project (id, name, created_utc) VALUES (1, 'old', '2026-01-01T00:00:00+00:00')")
    conn.execute("INSERT INTO cpiii_point VALUES ('CP1', 1.0, 2.0, 3.0, 'a.csv', 2, 'x')")
    conn.execute("INSERT INTO session (name, created_utc, state, source, meta_json) VALUES ('s1', 'x', 'open', 'live', ?)",
                 (st.meta_to_json(SessionMeta(latitude_rad=0.5)),))
    tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    assert "note" not in tables and "track_row" not in tables
    conn.close()

    with ProjectStore.open(path) as s:
        assert s.info().schema_version == st.SCHEMA_VERSION
        assert s.cpiii_points() == [ControlPoint("CP1", 1.0, 2.0, 3.0, "a.csv", 2)]
        sid = s.session("s1").session_id
        s.add_note(sid, NoteRecord(12.5, "ballast missing", chainage_m=1003.2))
        assert s.notes(sid)[0].text == "ballast missing"
        assert st.settings_to_json(s.settings()) == st.settings_to_json(ProjectSettings())  # v1 file had no settings row: defaults


def test_failed_migration_rolls_back(tmp_path, monkeypatch):
    path = tmp_path / st.STORE_FILE
    conn = st.connect(path)
    st.migrate(conn, target=1)

    def broken(c):
        c.execute("CREATE TABLE half_done (a)")
        raise RuntimeError("boom")

    monkeypatch.setattr(st, "MIGRATIONS", [st.MIGRATIONS[0], broken])
    monkeypatch.setattr(st, "SCHEMA_VERSION", 2)
    with pytest.raises(RuntimeError, match="boom"):
        st.migrate(conn)
    assert st.schema_version(conn) == 1
    assert conn.execute("SELECT COUNT(*) FROM sqlite_master WHERE name = 'half_done'").fetchone()[0] == 0


def test_settings_round_trip(store):
    s = ProjectSettings(latitude_rad=0.7, trolley=TrolleyGeometry(prism_lever_arm_m=np.array([0.1, 0.2, -0.7])),
                        imu=IMU_PRESETS["fog"], tolerance_set="TB10754-static", max_point_residual_m=0.003,
                        polar_model=PolarModel(curvature_refraction=False, grid_scale=1.00001))
    store.set_settings(s)
    got = store.settings()
    np.testing.assert_array_equal(got.trolley.prism_lever_arm_m, [0.1, 0.2, -0.7])
    assert got.imu == IMU_PRESETS["fog"]
    assert got.tolerance_set == "TB10754-static" and got.max_point_residual_m == 0.003
    assert got.latitude_rad == 0.7
    assert got.resection_config().model == PolarModel(curvature_refraction=False, grid_scale=1.00001)


def test_session_meta_json_round_trip_keeps_nan_and_none():
    meta = SessionMeta(latitude_rad=0.3, imu=None, design_alignment=None)
    back = st.meta_from_json(st.meta_to_json(meta))
    assert back.imu is None and np.isnan(back.initial_heading_rad)
    meta2 = ProjectSettings().session_meta("alignment.xml")
    back2 = st.meta_from_json(st.meta_to_json(meta2))
    assert back2.imu == IMU_PRESETS["rlg"] and back2.design_alignment == "alignment.xml"
    assert isinstance(back2.trolley.prism_lever_arm_m, np.ndarray)


def test_raw_rows_are_append_only(store):
    sid = store.create_session("s").session_id
    with RecordWriter(store.path, sid) as w:
        w.append("imu", 1.0, b"\x00\x01raw")
        w.append_records("imu_sample", [ImuRecord(1.0, 0, 0, 0, 0, 0, -9.8)])
        w.append_records("odometer_sample", [OdometerRecord(1.0, 0.0)])
    fid = store.add_fix(sid, FixRecord(2.0, "S1", 1, 2, 3, 1e-3, 1e-3, 1e-3))
    c = store.connection
    for sql in ["UPDATE raw_chunk SET payload = x'00'", "DELETE FROM raw_chunk",
                "UPDATE imu_sample SET wx_rad_s = 1", "DELETE FROM odometer_sample",
                "UPDATE fix SET e_m = 0", "DELETE FROM fix_decision"]:
        with pytest.raises(sqlite3.IntegrityError, match="append-only"):
            c.execute(sql)
    assert store.raw_chunks(sid) == [st.RawChunk("imu", 1.0, b"\x00\x01raw")]
    assert store.fixes(sid)[0].fix_id == fid


def test_writer_commits_within_a_second_for_a_reader(store):
    sid = store.create_session("live").session_id
    reader = sqlite3.connect(store.path)
    w = RecordWriter(store.path, sid, flush_interval_s=0.5, max_rows=10**6)
    try:
        delays = []
        for k in range(3):
            w.append("ts", float(k), f"%R1P,0,0:0,{k}\r\n".encode())
            t0 = time.monotonic()
            while reader.execute("SELECT COUNT(*) FROM raw_chunk").fetchone()[0] < k + 1:
                assert time.monotonic() - t0 < 1.0, "row not visible to a reader within 1 s"
                time.sleep(0.01)
            delays.append(time.monotonic() - t0)
        assert max(delays) < 1.0
    finally:
        w.close()
        reader.close()


def test_writer_commits_early_when_many_rows_and_flushes_on_close(store):
    sid = store.create_session("burst").session_id
    reader = sqlite3.connect(store.path)
    w = RecordWriter(store.path, sid, flush_interval_s=1.0, max_rows=100)
    w.append_records("imu_sample", [ImuRecord(k * 0.005, 0, 0, 1e-5, 0, 0, -9.8) for k in range(150)])
    t0 = time.monotonic()
    while reader.execute("SELECT COUNT(*) FROM imu_sample").fetchone()[0] < 150:
        assert time.monotonic() - t0 < 0.5
        time.sleep(0.005)
    w.append_records("gauge", [GaugeRecord(1.0, 1.4351)])
    w.close()  # must not lose the last queued row
    assert reader.execute("SELECT COUNT(*) FROM gauge_sample").fetchone()[0] == 1
    reader.close()
    with pytest.raises(StoreError, match="closed"):
        w.append("x", 0.0, b"")
    w2 = RecordWriter(store.path, sid)
    with pytest.raises(TypeError):
        w2.append_records("imu_sample", [GaugeRecord(1.0, 1.0)])
    with pytest.raises(StoreError, match="unknown record table"):
        w2.append_records("raw_chunk", [])
    w2.close()


def test_sigkill_loses_at_most_a_second(tmp_path):
    s = ProjectStore.create(tmp_path, "k")
    sid = s.create_session("s").session_id
    s.close()
    code = textwrap.dedent(f"""
        import time
        from survey.store import RecordWriter
        w = RecordWriter({str(s.path)!r}, {sid}, flush_interval_s=0.5)
        print("ready", flush=True)
        while True:
            w.append("imu", time.time(), b"x" * 64)
            time.sleep(0.002)
    """)
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    assert p.stdout.readline().strip() == b"ready"
    time.sleep(1.5)
    t_kill = time.time()
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    with ProjectStore.open(s.path) as again:
        chunks = again.raw_chunks(sid, "imu")
    assert len(chunks) > 100
    assert t_kill - chunks[-1].t_host_s < 1.0


def test_fix_decisions_are_appended(store):
    sid = store.create_session("s").session_id
    a = store.add_fix(sid, FixRecord(10.0, "S1", 1.0, 2.0, 3.0, 6e-4, 6e-4, 6e-4))
    b = store.add_fix(sid, FixRecord(20.0, "S2", 1.5, 2.5, 3.5, 6e-4, 6e-4, 6e-4, accepted=False,
                                     reason="innovation 4.2 sigma"))
    assert [f.accepted for f in store.fixes(sid)] == [True, False]
    assert store.fixes(sid)[1].reason == "innovation 4.2 sigma"
    store.decide_fix(b, True, "crew accepted")
    store.decide_fix(a, False, "undone")
    got = store.fixes(sid, accepted_only=True)
    assert [f.fix_id for f in got] == [b] and got[0].reason == "crew accepted"


def test_station_setup_round_trip(store):
    sid = store.create_session("s").session_id
    cov = np.diag([1e-8, 2e-8, 3e-8, 1e-12])
    setup = StationSetupRecord(t_s=5.0, station_enh_m=np.array([500000.1, 3000000.2, 45.3]), orientation_rad=1.2,
                               covariance=cov, sigma0=0.93, dof=20, excluded=("CP03R",))
    obs = [SetupObservation("CP01L", 0.1, 1.57, 30.0, True, 1e-6, -2e-6, 3e-4, 1e-4, 3e-4, -1e-4, 1.2, False, ""),
           SetupObservation("CP03R", 2.1, 1.56, 80.0, False, flagged=True, reason="standardized residual 7.1 > 3.29")]
    setup_id = store.add_station_setup(sid, setup, obs)
    (got,) = store.station_setups(sid)
    assert got.setup_id == setup_id and got.excluded == ("CP03R",) and got.dof == 20
    np.testing.assert_array_equal(got.station_enh_m, setup.station_enh_m)
    np.testing.assert_array_equal(got.covariance, cov)
    back = store.setup_observations(setup_id)
    assert back[0] == obs[0]
    assert back[1].reason == obs[1].reason and np.isnan(back[1].across_m) and not back[1].used


def test_stops_events_and_sessions(store):
    s = store.create_session("a")
    with pytest.raises(StoreError, match="already exists"):
        store.create_session("a")
    store.add_stop(s.session_id, StopRecord(0.0, 900.0, "CP0101/0102", 1000.0))
    store.add_event(s.session_id, SessionEvent(950.0, "pause", "train"))
    store.add_event(s.session_id, SessionEvent(1010.0, "resume"))
    assert [e.kind for e in store.events(s.session_id)] == ["pause", "resume"]
    assert store.stops(s.session_id)[0].label == "CP0101/0102"
    store.set_session_state(s.session_id, "ended")
    assert store.session("a").state == "ended"
    assert st.meta_to_json(store.session("a").meta) == st.meta_to_json(ProjectSettings().session_meta())
    assert [x.name for x in store.sessions()] == ["a"]
    with pytest.raises(sqlite3.IntegrityError, match="append-only"):
        store.connection.execute("DELETE FROM session_event")


def test_track_rows_round_trip(store):
    sid = store.create_session("s").session_id
    n = 5
    tr = TrackResult(np.arange(n) * 0.625, np.arange(3 * n, dtype=float).reshape(n, 3) + 1e5, np.full((n, 3), 3e-4),
                     np.array([1e-3, np.nan, 0, 0, 0]), np.zeros(n), np.full(n, np.nan), np.zeros(n), np.zeros(n))
    run = store.add_track(sid, "interval", 0.0, 60.0, tr)
    (info,) = store.processing_runs(sid)
    assert info.run_id == run and info.row_count == n and info.kind == "interval"
    back = store.track(run)
    for name in ("chainage_m", "enh_m", "sigma_enh_m", "lateral_dev_m", "gauge_m"):
        np.testing.assert_array_equal(getattr(back, name), getattr(tr, name))


def test_an_interval_summary_is_its_run_and_its_event_or_nothing(store, monkeypatch):
    # two transactions left a run without its event when the session died between them, and
    # the resume, which summarises an interval without an event again, stored it twice
    sid = store.create_session("s").session_id
    n = 3
    tr = TrackResult(np.arange(n) * 0.625, np.zeros((n, 3)), np.full((n, 3), 3e-4), np.zeros(n), np.zeros(n),
                     np.zeros(n), np.zeros(n), np.zeros(n))
    run = store.add_interval(sid, 2.0, 55.0, tr, {"seconds": 0.02, "defects": 1, "summary": "interval 0.0-60.0 m"})
    (event,) = store.events(sid)
    assert (event.kind, event.t_s) == ("interval", 55.0)
    assert json.loads(event.detail) == {"run_id": run, "t_start_s": 2.0, "t_end_s": 55.0, "seconds": 0.02,
                                        "defects": 1, "summary": "interval 0.0-60.0 m"}
    assert [(r.run_id, r.kind, r.row_count) for r in store.processing_runs(sid)] == [(run, "interval", n)]

    def dies(*args):
        raise KeyboardInterrupt("killed between the run and its event")

    monkeypatch.setattr(ProjectStore, "_insert_event", staticmethod(dies))
    with pytest.raises(KeyboardInterrupt):
        store.add_interval(sid, 55.0, 97.0, tr, {})
    assert len(store.processing_runs(sid)) == 1 and len(store.events(sid)) == 1
    assert store.connection.execute("SELECT COUNT(*) FROM track_row").fetchone()[0] == n


def test_raw_session_round_trip_arrays(store):
    rng = np.random.default_rng(0)
    n = 1000
    raw = RawSession(
        meta=ProjectSettings().session_meta(),
        imu_t_s=np.arange(n) * 0.005, imu_w_rad_s=rng.normal(size=(n, 3)), imu_f_m_s2=rng.normal(size=(n, 3)),
        odo_t_s=np.arange(n) * 0.005, odo_distance_m=np.cumsum(rng.uniform(0, 1e-3, n)),
        fixes=Fixes(np.array([0.0, 4.0]), np.array(["S1", "S2"], dtype=object),
                    rng.normal(size=(2, 3)) * 1e5, np.full((2, 3), 6e-4)),
        gauge_t_s=None, gauge_m=None)
    store.import_raw_session("imp", raw)
    back, design = store.raw_session("imp")
    assert design is None and back.gauge_t_s is None
    for name in ("imu_t_s", "imu_w_rad_s", "imu_f_m_s2", "odo_t_s", "odo_distance_m"):
        np.testing.assert_array_equal(getattr(back, name), getattr(raw, name))
    np.testing.assert_array_equal(back.fixes.enh_m, raw.fixes.enh_m)
    assert list(back.fixes.point) == ["S1", "S2"]
    counts = {c.table: c.rows for c in store.record_counts(store.session("imp").session_id)}
    assert counts["imu_sample"] == n and counts["fix"] == 2
    with pytest.raises(StoreError, match="already exists"):
        store.import_raw_session("imp", raw)


def _raw_with_fix_covariances():
    n = 100
    cov = np.array([[1.1e-7, 2e-9, -3e-9], [-1.2e-7, 4e-9, 5e-9], [0.9e-7, -6e-9, 7e-9]])
    return RawSession(
        meta=ProjectSettings().session_meta(),
        imu_t_s=np.arange(n) * 0.1, imu_w_rad_s=np.zeros((n, 3)), imu_f_m_s2=np.zeros((n, 3)),
        odo_t_s=np.arange(n) * 0.1, odo_distance_m=np.arange(n) * 0.01,
        fixes=Fixes(np.array([0.0, 4.0, 8.0]), np.array(["S1", "S2", "S3"], dtype=object),
                    np.array([[1e5, 2e5, 50.0]] * 3), np.full((3, 3), 6e-4), cov),
        gauge_t_s=None, gauge_m=None)


def test_a_crop_keeps_the_fix_covariances_with_their_fixes():
    # a session whose alignment restarted after a fix: the crop kept the covariances of the fix it
    # dropped, each fix took the one before's, and the session's end refused its own fixes.csv
    # ("row 2, column cov_EN_m2: ... it is no covariance") or processed with wrong correlations
    from survey.store import crop_session

    raw = _raw_with_fix_covariances()
    cropped = crop_session(raw, 2.0).fixes
    assert list(cropped.point) == ["S2", "S3"]
    np.testing.assert_array_equal(cropped.cov_m2, raw.fixes.cov_m2[1:])


def test_imported_fixes_keep_their_covariances(store):
    # a session folder whose fixes.csv has the cov_EN_m2, cov_EH_m2, cov_NH_m2 columns (a field
    # session's, exported) was imported without them: exported again, its fixes were uncorrelated
    # and the processed lateral sigma 2.5 x the error
    raw = _raw_with_fix_covariances()
    store.import_raw_session("imp", raw)
    np.testing.assert_array_equal(store.raw_session("imp")[0].fixes.cov_m2, raw.fixes.cov_m2)
    # without the columns the file is given back as it was: no covariances
    store.import_raw_session("plain", replace(raw, fixes=replace(raw.fixes, cov_m2=None)))
    assert store.raw_session("plain")[0].fixes.cov_m2 is None


def test_resection_rows_round_trip(store):
    from trolley.resection import observations_from_station, resect

    ids = ["A", "B", "C", "D", "E"]
    pts = np.array([[10.0, 40, 1], [45, 5, -1], [-30, -35, 0.5], [-40, 20, 0], [20, -45, 2]]) + [5e5, 3.1e6, 40]
    station = np.array([5e5 + 1.0, 3.1e6 - 2.0, 41.5])
    wrong = pts.copy()
    wrong[3, 0] += 0.01
    obs = observations_from_station(station, 0.3, wrong)
    cfg = ProjectSettings().resection_config()
    res = resect(ids, pts, obs, cfg, exclude=["D"])
    setup, rows = st.setup_rows(res, ids, obs, t_s=3.0)
    sid = store.create_session("s").session_id
    setup_id = store.add_station_setup(sid, setup, rows)
    back = store.setup_observations(setup_id)
    assert [r.point_id for r in back] == ids
    assert [r.used for r in back] == [True, True, True, False, True]
    assert back[3].reason == "excluded by the crew" and np.isnan(back[3].across_m)
    assert back[0].max_standardized == res.residuals[0].max_standardized
    (got,) = store.station_setups(sid)
    np.testing.assert_allclose(got.station_enh_m, station, atol=1e-8)
    assert got.excluded == ("D",)
