"""Scripted field sessions with the simulated devices on ptys; SIGKILL in an interval and resume.

The same simulated survey (tests/session_project.py) is surveyed twice: once without interruption,
once killed with SIGKILL in the middle of the second interval and resumed with
``trolley survey resume``. The decoded record counts must be equal and the final tracks agree
within 0.05 mm.
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from polling import count_in_store
from session_project import fix_covariance_by_hand, fix_sigmas_by_hand, make_project, shared_copy

TROLLEY = [sys.executable, "-m", "survey.cli"]
SPEEDUP = "25"
SCRIPT = "fix\nmove\nfix\nnote hello from the crew\nstation\nmove\nfix\nend\n"


def run_cli(args, cwd, timeout=120):
    return subprocess.run(TROLLEY + args, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "COLUMNS": "160"})


def _reference(root):
    make_project(root / "projects", tolerance_set="en13848_5_alert")  # not the default set
    (root / "crew.txt").write_text(SCRIPT)
    r = run_cli(["survey", "start", "t1", "--root", "projects", "--session", "ref", "--simulate",
                 "--speedup", SPEEDUP, "--script", "crew.txt"], root)
    assert r.returncode == 0, r.stderr[-3000:]
    return r


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """The reference session, run once for all workers; each worker's tests work on its own copy."""
    return shared_copy(tmp_path_factory, "session_run", _reference)


def store(root):
    from survey.store import ProjectStore

    return ProjectStore.open(root / "projects" / "t1")


def final_track(st, name):
    sid = st.session(name).session_id
    run = [r for r in st.processing_runs(sid) if r.kind == "final"][-1]
    return st.track(run.run_id)


def counts(st, name):
    sid = st.session(name).session_id
    return {c.table: c.rows for c in st.record_counts(sid) if c.table != "raw_chunk"}


def test_scripted_session_records_everything_and_processes(project):
    root, r = project
    with store(root) as st:
        sid = st.session("ref").session_id
        assert st.session("ref").state == "ended"
        # every simulated sample arrived through the ptys, decoded exactly (ISA-100C counts: 1e-9 rad)
        from survey.commands.survey import simulated_world

        raw = simulated_world(st, 1.0).sim.session
        t, w, f = st.imu_arrays(sid)
        assert t.size == raw.imu_t_s.size
        assert np.max(np.abs(t - raw.imu_t_s)) < 1e-9
        assert np.max(np.abs(w - raw.imu_w_rad_s)) <= 1e-9 * 200 / 2 + 1e-15
        ot, od = st.odometer_arrays(sid)
        # the driver withholds the first replies until they confirm each other (drivers/encoder.py)
        from survey.session.simworld import SIM_ODOMETER

        k = SIM_ODOMETER.confirm - 1
        assert np.array_equal(ot, raw.odo_t_s[k:]) and np.max(np.abs(od - raw.odo_distance_m[k:])) < 1e-9
        gt, gm = st.gauge_arrays(sid)
        assert gt.size == raw.gauge_t_s.size and np.max(np.abs(gm - raw.gauge_m)) <= 5e-6 + 1e-12  # 0.01 mm
        # raw bytes are kept per device: 56-byte RAWIMUSXB frames
        imu_bytes = st.connection.execute("SELECT SUM(LENGTH(payload)) FROM raw_chunk WHERE session_id = ? AND "
                                          "device = 'imu'", (sid,)).fetchone()[0]
        assert imu_bytes == 56 * raw.imu_t_s.size
        # what the session sent is kept too: one poll per odometer sample, the GeoCOM requests
        polls = st.connection.execute("SELECT SUM(LENGTH(payload)) FROM raw_chunk WHERE session_id = ? AND "
                                      "device = 'odometer>'", (sid,)).fetchone()[0]
        assert polls == 5 * raw.odo_t_s.size  # "$0R0\r"
        requests = b"".join(r[0] for r in st.connection.execute(
            "SELECT payload FROM raw_chunk WHERE session_id = ? AND device = 'totalstation>' ORDER BY id", (sid,)))
        assert requests.count(b"%R1Q,9037,") == 8 + 8 + 4  # ATR on 2 x 8 CPIII points and 4 prism fixes
        fixes = st.fixes(sid)
        # the third fix is the overlap check of the station change at the second stop
        assert [f.accepted for f in fixes] == [True, True, True, True]
        setups = st.station_setups(sid)
        assert len(setups) == 2 and [f.setup_id for f in fixes] == [setups[0].setup_id] * 2 + [setups[1].setup_id] * 2
        assert np.hypot(*(setups[1].station_enh_m - setups[0].station_enh_m)[:2]) > 50.0  # it moved ahead
        assert abs(fixes[2].t_s - fixes[1].t_s) < 8.0  # same stop
        # each fix stands at a simulated stop, within 2 mm of the simulated prism (0.6 mm noise per axis)
        from survey.session.simworld import prism_position_enh

        sim = simulated_world(st, 1.0).sim
        for fx in fixes:
            d = np.array([fx.e_m, fx.n_m, fx.h_m]) - prism_position_enh(sim, fx.t_s)
            assert np.max(np.abs(d)) < 0.003
        # every stop, the static alignment's at the start and the one the session ends at included
        # (bug hunt 2026-11-26: both were missing), in time order with consecutive labels
        stops = st.stops(sid)
        assert [s.label for s in stops] == ["S000", "S001", "S002"]
        assert np.allclose([s.chainage_m for s in stops], [0.0, 60.0, 120.0], atol=0.05)
        assert stops[0].t_start_s == pytest.approx(t[0], abs=1.0)
        assert all(a.t_end_s <= b.t_start_s for a, b in zip(stops, stops[1:]))
        assert all(any(s.t_start_s <= fx.t_s <= s.t_end_s for s in stops) for fx in fixes)
        notes = st.notes(sid)
        assert [n.text for n in notes] == ["hello from the crew"]
        # the processed summary names the project and the session, as the sheet does
        import json

        doc = json.loads((root / "projects" / "t1" / "sessions" / "ref" / "processed" / "summary.json").read_text())
        assert (doc["project"], doc["session"]) == ("t1", "ref")
        # the crew's note reaches the client: in the field record and on the sheet's Notes
        from openpyxl import load_workbook

        record = json.loads((root / "projects/t1/sessions/ref/processed/field_record.json").read_text())
        assert [(n["text"], round(n["chainage_m"])) for n in record["notes"]] == [("hello from the crew", 60)]
        ws = load_workbook(root / "projects/t1/sessions/ref/survey.xlsx")["Notes"]
        cells = [c.value for row in ws.iter_rows() for c in row]
        assert "hello from the crew" in cells
        assert abs(notes[0].chainage_m - 60.0) < 0.05  # taken at the second stop
        assert all(s.accepted and s.dof > 0 for s in setups)
        track = final_track(st, "ref")
        assert len(track) > 150 and np.nanmax(track.sigma_enh_m) < 0.002
    text = " ".join(r.stderr.split())
    assert "overlap check at FIX002: new - old station" in text and "within the tolerance of 2.0 mm" in text
    assert "survey.xlsx" in r.stdout and (root / "projects/t1/sessions/ref/survey.xlsx").is_file()
    # the output folder is the session's: marked, and never written by another session
    out = root / "projects/t1/sessions/ref"
    assert (out / ".made-by-trolley").read_text().strip() == "survey session ref"
    before = {f: f.read_bytes() for f in (out / "session").iterdir() if f.is_file()}
    other = run_cli(["survey", "start", "t1", "--root", "projects", "--session", "other", "--simulate",
                     "--speedup", SPEEDUP, "--script", "crew.txt", "--out", str(out)], root)
    assert other.returncode == 2 and "was not made by `trolley survey session other`" in other.stderr
    assert {f: f.read_bytes() for f in (out / "session").iterdir() if f.is_file()} == before
    with store(root) as st:
        assert "other" not in [x.name for x in st.sessions()]      # refused before it was stored


def test_each_fix_carries_its_station_setups_error_in_its_sigma(project):
    # sigma^2 = the polar measurement's variance from the instrument sigmas + the setup's station and
    # orientation covariance carried to the fix, written out by hand (session_project); both scaled
    # by sigma0^2 when sigma0 > 1 (tests/test_session_overlap.py: sigma0 about 2)
    root, _ = project
    with store(root) as st:
        rec = st.session("ref")
        instrument = st.settings().instrument
        setups = {s.setup_id: s for s in st.station_setups(rec.session_id)}
        fixes = st.fixes(rec.session_id)
        for fx in fixes:
            np.testing.assert_allclose([fx.sigma_e_m, fx.sigma_n_m, fx.sigma_h_m],
                                       fix_sigmas_by_hand(fx, setups[fx.setup_id], instrument), rtol=1e-9)
            # the distance sigma lies along the line of sight, in E and N together
            assert np.hypot(fx.sigma_e_m, fx.sigma_n_m) > instrument.distance_m
    # the raw session handed to the engine carries them (fixes.csv, FORMATS.md section 1)
    import pandas as pd

    csv = pd.read_csv(root / "projects/t1/sessions/ref/session/fixes.csv")
    stored = np.array([[f.sigma_e_m, f.sigma_n_m, f.sigma_h_m] for f in fixes if f.accepted])
    np.testing.assert_allclose(csv[["sigma_E_m", "sigma_N_m", "sigma_H_m"]].to_numpy(), stored, rtol=1e-15)
    # and their correlations (a polar fix's E and N are correlated by its line of sight; as
    # independent axes the demo's lateral sigma was 2.5 x its error), computed again at the export
    # with the project's polar model (curvature and refraction: 1e-4 of the E-H and N-H terms here;
    # the hand computation is flat)
    by_hand = np.array([fix_covariance_by_hand(f, setups[f.setup_id], instrument) for f in fixes if f.accepted])
    np.testing.assert_allclose(csv[["cov_EN_m2", "cov_EH_m2", "cov_NH_m2"]].to_numpy(),
                               by_hand[:, [0, 0, 1], [1, 2, 2]], rtol=1e-3, atol=1e-16)
    assert np.all(np.abs(csv["cov_EN_m2"]) > 0.1 * csv["sigma_E_m"] * csv["sigma_N_m"])


def test_live_summaries_and_the_sheet_use_the_projects_tolerance_set(project):
    import openpyxl

    root, r = project
    text = " ".join(r.stderr.split())
    with store(root) as st:
        intervals = [e for e in st.events(st.session("ref").session_id) if e.kind == "interval"]
    # the live summary of each interval (the overlap check closes one of no length too)
    assert len(intervals) == 3 and text.count("against en13848_5_alert") == 3
    assert "hsr_ballastless_static" not in text
    wb = openpyxl.load_workbook(root / "projects/t1/sessions/ref/survey.xlsx", read_only=True)
    cells = [str(c) for ws in wb.worksheets for row in ws.iter_rows(values_only=True) for c in row if c is not None]
    i = cells.index("Tolerance set")
    assert cells[i + 1].startswith("en13848_5_alert:")


def test_export_session_then_process_gives_the_stored_final_track(project):
    """`trolley project export-session` and the end of the session write the same folder, so
    `trolley process` on the export reproduces the final track byte for byte."""
    root, _ = project
    r = run_cli(["project", "export-session", "--project", "t1", "--root", "projects", "--session", "ref",
                 "--out", "exported"], root)
    assert r.returncode == 0, r.stderr
    r = run_cli(["process", "exported", "--out", "reprocessed"], root)
    assert r.returncode == 0, r.stderr
    final = root / "projects/t1/sessions/ref"
    for name in sorted(p.name for p in (final / "session").iterdir()):
        assert (root / "exported" / name).read_bytes() == (final / "session" / name).read_bytes(), name
    assert (root / "reprocessed/track.csv").read_bytes() == (final / "processed/track.csv").read_bytes()


def _odometer_distance(db: Path, name: str) -> float:
    try:
        c = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1.0)
        sid = c.execute("SELECT id FROM session WHERE name = ?", (name,)).fetchone()
        if not sid:
            return 0.0
        return float(c.execute("SELECT COALESCE(MAX(distance_m), 0) FROM odometer_sample WHERE session_id = ?",
                               sid).fetchone()[0])
    except sqlite3.Error:
        return 0.0


def test_sigkill_in_an_interval_then_resume_matches_an_uninterrupted_run(project):
    root, _ = project
    db = root / "projects" / "t1" / "project.sqlite"
    # slower than the reference run (more time to kill inside the interval); the simulated world waits
    # for the crew's measurements, so the speed-up does not change the result
    p = subprocess.Popen(TROLLEY + ["survey", "start", "t1", "--root", "projects", "--session", "killed",
                                    "--simulate", "--speedup", "12", "--script", "crew.txt"],
                         cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 90
    while _odometer_distance(db, "killed") < 80.0:  # second interval: 60 .. 120 m
        assert p.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    at_kill = _odometer_distance(db, "killed")
    assert 80.0 <= at_kill < 120.0
    # the odometer rows of the last metres before the 60 m stop were not committed when the
    # process died, while the fixes at that stop were: the last fix is newer than the odometer data
    _lose_odometer_rows(db, "killed", "distance_m > 55.0")
    r = run_cli(["survey", "resume", "t1", "--root", "projects", "--session", "killed", "--speedup", SPEEDUP], root)
    assert r.returncode == 0, r.stderr[-3000:]
    text = " ".join(r.stderr.split())
    assert "resumed session killed: 3 fixes kept" in text
    # the chainage counts from the odometer at the last fix, once those data have come again
    assert "standing at 120.0 m" in text
    with store(root) as st:
        assert counts(st, "killed") == counts(st, "ref")
        assert [f.accepted for f in st.fixes(st.session("killed").session_id)] == [True] * 4
        # the fix after the resume carries the restored setup's error in its sigma, as uninterrupted
        sig = [[(f.sigma_e_m, f.sigma_n_m, f.sigma_h_m) for f in st.fixes(st.session(n).session_id)]
               for n in ("ref", "killed")]
        np.testing.assert_allclose(sig[1], sig[0], rtol=1e-9)
        a, b = final_track(st, "ref"), final_track(st, "killed")
        assert np.array_equal(a.chainage_m, b.chainage_m)
        assert np.max(np.abs(a.enh_m - b.enh_m)) < 0.05e-3
        kinds = [e.kind for e in st.events(st.session("killed").session_id)]
        assert "resumed" in kinds and kinds[-1] == "end"


def test_sigterm_in_an_interval_ends_as_ctrl_c_then_resume_matches_an_uninterrupted_run(project):
    """SIGTERM (a logout, a service stop, a CI timeout) ended the process at once, as SIGKILL does;
    now it ends the session as Ctrl-C does (survey.errors.sigterm_as_interrupt): the devices, the
    simulated world and the session's threads stopped (all daemons, or joined in
    FieldSession._shutdown: none keeps the process alive), the resume command said, exit 143.
    The resumed session gives the uninterrupted one's result, as after a kill."""
    root, _ = project
    db = root / "projects" / "t1" / "project.sqlite"
    err = root / "termed.err"
    with open(err, "w") as fh:
        p = subprocess.Popen(TROLLEY + ["survey", "start", "t1", "--root", "projects", "--session", "termed",
                                        "--simulate", "--speedup", "40", "--script", "crew.txt"],
                             cwd=root, stdout=subprocess.DEVNULL, stderr=fh, env={**os.environ, "COLUMNS": "300"})
    deadline = time.monotonic() + 90
    while _odometer_distance(db, "termed") < 20.0:  # first interval: 0 .. 60 m
        assert p.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    p.send_signal(signal.SIGTERM)
    assert p.wait(timeout=10) == 143          # (measured: 0.3 s; a thread that kept it alive would time out)
    text = " ".join(err.read_text().split())
    assert ("error: interrupted (SIGTERM); everything recorded so far is in the store try: `trolley survey resume "
            "t1 --session termed` continues it") in text, text[-2000:]
    with store(root) as st:
        assert st.session("termed").state != "ended"
        assert 20.0 <= float(st.odometer_arrays(st.session("termed").session_id)[1].max()) < 60.0
    out = root / "projects" / "t1" / "sessions" / "termed"
    # its marker only (the outputs are written at the end): nothing hidden left by the interrupt
    assert [q.name for q in out.rglob(".*")] == [".made-by-trolley"]
    r = run_cli(["survey", "resume", "t1", "--root", "projects", "--session", "termed", "--speedup", "40"], root)
    assert r.returncode == 0, r.stderr[-3000:]
    with store(root) as st:
        assert counts(st, "termed") == counts(st, "ref")
        assert [f.accepted for f in st.fixes(st.session("termed").session_id)] == [True] * 4
        a, b = final_track(st, "ref"), final_track(st, "termed")
        assert np.array_equal(a.chainage_m, b.chainage_m)
        assert np.max(np.abs(a.enh_m - b.enh_m)) < 0.05e-3


def _interval_summaries(st, name):
    """(interval events, interval processing runs, the chainage span each summary shows)."""
    sid = st.session(name).session_id
    events = [json.loads(e.detail) for e in st.events(sid) if e.kind == "interval"]
    runs = [r for r in st.processing_runs(sid) if r.kind == "interval"]
    return len(events), len(runs), [e["summary"].split(":")[0] for e in events]


def test_sigkill_before_an_interval_summary_is_stored_then_resume_summarises_it(project):
    """The summary of the interval a fix closes is computed on a thread and stored at the next
    refresh; a kill in between lost it for good (bug hunt 2026-11-26: one ``interval`` event
    instead of two). Killed as the script step of the second fix is stored (before its summary,
    in every run measured; a later kill makes the test pass without testing it, never fail)."""
    root, _ = project
    db = root / "projects" / "t1" / "project.sqlite"
    p = subprocess.Popen(TROLLEY + ["survey", "start", "t1", "--root", "projects", "--session", "cut",
                                    "--simulate", "--speedup", "40", "--script", "crew.txt"],
                         cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    step_3 = ("SELECT COUNT(*) FROM session_event e JOIN session s ON s.id = e.session_id "
              "WHERE s.name = 'cut' AND e.kind = 'script' AND e.detail LIKE '3 %'")
    deadline = time.monotonic() + 90
    while not count_in_store(db, step_3):
        assert p.poll() is None and time.monotonic() < deadline
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    r = run_cli(["survey", "resume", "t1", "--root", "projects", "--session", "cut", "--speedup", "40"], root)
    assert r.returncode == 0, r.stderr[-3000:]
    with store(root) as st:
        ref, cut = _interval_summaries(st, "ref"), _interval_summaries(st, "cut")
    # as many summaries (events and runs) as the uninterrupted run, of the same intervals
    assert ref[:2] == (3, 3) and cut == ref, (cut, ref)


def _lose_odometer_rows(db: Path, name: str, where: str) -> None:
    """The odometer rows ``where`` were not committed when the process died (the rows are
    append-only: the test lifts the store's trigger for this one delete)."""
    with sqlite3.connect(db) as c:
        sid = c.execute("SELECT id FROM session WHERE name = ?", (name,)).fetchone()[0]
        trigger = c.execute("SELECT sql FROM sqlite_master WHERE name = 'odometer_sample_no_delete'").fetchone()[0]
        c.execute("DROP TRIGGER odometer_sample_no_delete")
        c.execute(f"DELETE FROM odometer_sample WHERE session_id = ? AND {where}", (sid,))
        c.execute(trigger)


def _rows(db: Path, name: str, table: str) -> int:
    try:
        c = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1.0)
        try:
            sid = c.execute("SELECT id FROM session WHERE name = ?", (name,)).fetchone()
            return int(c.execute(f"SELECT COUNT(*) FROM {table} WHERE session_id = ?", sid).fetchone()[0]) if sid else 0
        finally:
            c.close()
    except sqlite3.Error:
        return 0


def _outcome(st, name):
    """(accepted fixes with their setup's index, overlap checks, final track) of a session."""
    sid = st.session(name).session_id
    setups = {s.setup_id: i for i, s in enumerate(st.station_setups(sid))}
    fixes = st.fixes(sid)
    accepted = [(f.point, setups[f.setup_id]) for f in fixes if f.accepted]
    overlaps = [(f.point, f.accepted, f.reason, (f.e_m, f.n_m, f.h_m)) for f in fixes
                if f.reason.startswith("overlap check")]
    return accepted, overlaps, final_track(st, name)


@pytest.mark.parametrize("when", ["measuring the new station", "new station stored"])
def test_sigkill_during_a_station_change_then_resume_matches_an_uninterrupted_run(project, when):
    """Killed while the CPIII points of the new station are measured, or once the new setup is
    stored (before or just after the overlap measurement): the resumed session continues the station
    change from its first step not stored. The same setups, the same accepted fixes and the same
    overlap check as the uninterrupted run; the final tracks agree within 0.05 mm."""
    root, _ = project
    db = root / "projects" / "t1" / "project.sqlite"
    name = "station-" + when.split()[0]
    p = subprocess.Popen(TROLLEY + ["survey", "start", "t1", "--root", "projects", "--session", name,
                                    "--simulate", "--speedup", SPEEDUP, "--script", "crew.txt"],
                         cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    table, n = ("session_event", None) if when.startswith("measuring") else ("station_setup", 2)
    deadline = time.monotonic() + 90
    while True:
        assert p.poll() is None and time.monotonic() < deadline
        if n is None:
            with contextlib.suppress(sqlite3.Error):
                c = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1.0)
                hit = c.execute("SELECT COUNT(*) FROM session_event e JOIN session s ON s.id = e.session_id "
                                "WHERE s.name = ? AND e.kind = 'station_change'", (name,)).fetchone()[0]
                c.close()
                if hit:
                    break
        elif _rows(db, name, table) >= n:
            break
        time.sleep(0.01)
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    with store(root) as st:
        sid = st.session(name).session_id
        before = (len(st.station_setups(sid)), len(st.fixes(sid)))
        t_fix = st.fixes(sid)[1].t_s
    assert before[1] == 2 or when.startswith("new")  # the overlap fix is not measured before its station
    # the odometer rows of the last seconds before the fix at the stop were not committed either:
    # the live filter gets the stored fixes once their data have come again
    _lose_odometer_rows(db, name, f"t_s > {t_fix - 3.0!r}")
    r = run_cli(["survey", "resume", "t1", "--root", "projects", "--session", name, "--speedup", SPEEDUP], root)
    assert r.returncode == 0, r.stderr[-3000:]
    with store(root) as st:
        fa, oa, ta = _outcome(st, "ref")
        fb, ob, tb = _outcome(st, name)
        assert len(st.station_setups(st.session(name).session_id)) == 2, before
        kinds = [e.kind for e in st.events(st.session(name).session_id)]
    assert fb == fa and len(fa) == 4, (before, r.stderr[-4000:])
    assert [o[:3] for o in ob] == [o[:3] for o in oa] and len(ob) == 1
    assert np.max(np.abs(np.subtract(ob[0][3], oa[0][3]))) < 1e-6  # the same measurement
    assert kinds.count("station_change") == 1
    assert np.array_equal(ta.chainage_m, tb.chainage_m)
    assert np.max(np.abs(ta.enh_m - tb.enh_m)) < 0.05e-3


def test_resume_of_an_ended_session_is_refused(project):
    root, _ = project
    r = run_cli(["survey", "resume", "t1", "--root", "projects", "--session", "ref"], root)
    assert r.returncode == 2 and "has ended" in r.stderr and "Traceback" not in r.stderr
    assert "--reopen" in r.stderr  # the way to add intervals to it


def _copy_without_final_run(root: Path, dst: Path) -> Path:
    """A copy of the project in the state a kill during the end's sheet leaves: the session
    ended and processed, but no "final" run (stored after the sheet), no survey.xlsx, and the
    writers' hidden temporaries. Returns the session's output folder in the copy."""
    import shutil

    shutil.copytree(root, dst)
    with sqlite3.connect(dst / "projects" / "t1" / "project.sqlite") as c:
        sid = c.execute("SELECT id FROM session WHERE name = 'ref'").fetchone()[0]
        runs = [r for (r,) in c.execute("SELECT id FROM processing_run WHERE session_id = ? AND kind = 'final'",
                                         (sid,))]
        for table in ("track_row", "processing_run"):
            trig = c.execute("SELECT name, sql FROM sqlite_master WHERE type = 'trigger' AND tbl_name = ? "
                             "AND name LIKE '%no_delete'", (table,)).fetchall()
            for name, _ in trig:
                c.execute(f"DROP TRIGGER {name}")
            key = "run_id" if table == "track_row" else "id"
            c.executemany(f"DELETE FROM {table} WHERE {key} = ?", [(r,) for r in runs])
            for _, sql in trig:
                c.execute(sql)
    out = dst / "projects" / "t1" / "sessions" / "ref"
    (out / "survey.xlsx").unlink()
    (out / ".survey.xlsx.abcd1234.xlsx").write_bytes(b"half a workbook")
    (out / "plots" / ".twist.png.k2j3h4g5.png").write_bytes(b"half a plot")
    (out / ".session.q1w2e3r4.partial").mkdir()                  # a raw session export cut short
    (out / ".session.q1w2e3r4.partial" / "imu.csv").write_bytes(b"t_s,wx")
    return out


def test_an_end_killed_before_the_sheet_is_done_again_on_resume(project, tmp_path):
    """kill -9 while the end writes the survey sheet (review of 2026-11-26): the session had
    ended, its "final" run was stored before the sheet, so resume said "nothing to resume" and the
    crew never got a sheet. The run is now stored last, and resume does the whole end again, the
    killed writers' temporaries removed."""
    root, _ = project
    out = _copy_without_final_run(root, tmp_path / "copy")
    sheet = root / "projects" / "t1" / "sessions" / "ref" / "survey.xlsx"
    before = sheet.stat().st_mtime_ns
    r = run_cli(["survey", "resume", "t1", "--root", "projects", "--session", "ref", "--simulate",
                 "--speedup", SPEEDUP], tmp_path / "copy")
    assert r.returncode == 0, r.stderr[-3000:]
    assert (out / "survey.xlsx").is_file() and (out / "plots" / "twist.png").is_file()
    # the copy resumed into its own folder: the start event keeps sessions/ref relative to the project
    assert sheet.stat().st_mtime_ns == before
    assert not [p.name for p in out.rglob(".*") if p.name != ".made-by-trolley"], list(out.rglob(".*"))
    with store(root) as st:
        original = final_track(st, "ref")
    with store(tmp_path / "copy") as st:
        sid = st.session("ref").session_id
        assert [p.kind for p in st.processing_runs(sid)].count("final") == 1
        again = final_track(st, "ref")
        assert st.session("ref").state == "ended"
    assert np.array_equal(again.chainage_m, original.chainage_m) and np.array_equal(again.enh_m, original.enh_m)


def test_the_final_run_is_stored_only_once_the_sheet_is_written(project, tmp_path, monkeypatch):
    from rich.console import Console

    import survey.export
    from survey.session.fieldsession import SessionOutcome
    from survey.session.final import process_stored_session

    root, _ = project
    out = _copy_without_final_run(root, tmp_path / "copy")

    def sheet_killed(*args, **kwargs):
        raise KeyboardInterrupt("killed while writing the sheet")

    monkeypatch.setattr(survey.export, "export_outputs", sheet_killed)
    with store(tmp_path / "copy") as st:
        sid = st.session("ref").session_id
        with pytest.raises(KeyboardInterrupt):
            process_stored_session(st, "ref", out, SessionOutcome(sid, 4), Console(file=open(os.devnull, "w")),
                                   "en13848_5_alert")
        assert [p.kind for p in st.processing_runs(sid)].count("final") == 0
    # the temporaries of the killed run before were removed as the end started again
    assert not (out / ".survey.xlsx.abcd1234.xlsx").exists() and not (out / "plots" / ".twist.png.k2j3h4g5.png").exists()


def test_reopening_a_simulated_session_recorded_to_its_end_is_refused_and_leaves_it_ended(project, tmp_path):
    root, _ = project
    import shutil

    shutil.copytree(root, tmp_path / "copy")
    (tmp_path / "copy" / "end.txt").write_text("end\n")
    r = run_cli(["survey", "resume", "t1", "--root", "projects", "--session", "ref", "--simulate", "--speedup",
                 SPEEDUP, "--reopen", "--script", "end.txt"], tmp_path / "copy")
    assert r.returncode == 2 and "recorded to the end" in r.stderr and "Traceback" not in r.stderr, r.stderr[-2000:]
    with store(tmp_path / "copy") as st:
        assert st.session("ref").state == "ended"
        assert "reopened" not in [e.kind for e in st.events(st.session("ref").session_id)]


def test_a_full_disk_at_the_end_names_the_folder_and_the_way_on(tmp_path, monkeypatch):
    # (the OSError of a full disk names no file: "error: No space left on device" said nothing)
    import errno
    from types import SimpleNamespace

    import survey.session.final
    from survey.session.errors import SessionAbort
    from survey.session.fieldsession import FieldSession

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(survey.session.final, "process_stored_session", full)
    fs = SimpleNamespace(accepted_fixes=[1, 2], static_start_s=0.0, rec=SimpleNamespace(session_id=1),
                         config=SimpleNamespace(out_dir=tmp_path / "out", project="site7"), name="ref", store=None,
                         console=None,
                         tolerance_name="default", say=print)
    with pytest.raises(SessionAbort) as exc:
        FieldSession._final_processing(fs)
    assert str(exc.value) == (f"end of session: cannot write the results into {tmp_path / 'out'} (No space left on "
                              "device); the session is stored")
    assert "trolley survey resume site7 --session ref" in exc.value.hint   # the project as given
