"""SIGKILL at the edges a field-crew bug hunt found (2026-11-26), then ``trolley survey resume``:
right after a scripted ``undo`` (it was done again on resume, undoing the fix before), and after
the session's last sample but before its end (the resume died with an internal error, for good).
The kill is timed by polling the store; a kill that comes later than the edge makes the test
pass without testing it, never fail."""
from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time

import numpy as np
import pytest

from session_project import make_project

TROLLEY = [sys.executable, "-m", "survey.cli"]


def _query(db, sql: str, *args):
    try:
        c = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=0.2)
        try:
            return c.execute(sql, args).fetchone()
        finally:
            c.close()
    except sqlite3.Error:
        return None


def _kill_when(root, session: str, script: str, condition, timeout_s: float = 90.0) -> None:
    (root / f"{session}.txt").write_text(script)
    p = subprocess.Popen(TROLLEY + ["survey", "start", "t1", "--root", "projects", "--session", session,
                                    "--simulate", "--speedup", "40", "--script", f"{session}.txt"],
                         cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert p.poll() is None, f"the session ended before the kill (exit {p.returncode})"
        assert time.monotonic() < deadline
    os.kill(p.pid, signal.SIGKILL)
    p.wait()


def _resume(root, session: str, *extra: str):
    r = subprocess.run(TROLLEY + ["survey", "resume", "t1", "--root", "projects", "--session", session,
                                  "--speedup", "40", *extra], cwd=root, capture_output=True, text=True, timeout=120,
                       env={**os.environ, "COLUMNS": "160"})
    assert r.returncode == 0, r.stderr[-3000:]
    return r


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    root = tmp_path_factory.mktemp("kill_edges")
    make_project(root / "projects")
    return root


def test_killed_after_a_scripted_undo_and_after_the_last_sample_the_resumes_end_it_right(root):
    # one session, two kills: right after the scripted undo, then (its resume) after the last
    # simulated sample but before the end
    from survey.commands.survey import simulated_world
    from survey.store import ProjectStore

    db = root / "projects" / "t1" / "project.sqlite"
    with ProjectStore.open(root / "projects" / "t1") as st:
        last_t = float(simulated_world(st, 1.0).sim.session.imu_t_s[-1])
    _kill_when(root, "undo", "fix\nmove\nfix\nmove\nfix\nundo\nend\n",
               lambda: (_query(db, "SELECT COUNT(*) FROM fix_decision WHERE reason LIKE 'undone%'") or (0,))[0] > 0)

    def after_the_last_sample():
        row = _query(db, "SELECT (SELECT MAX(t_s) FROM imu_sample) >= ?, (SELECT COUNT(*) FROM session_event "
                         "WHERE kind = 'end')", last_t - 1e-6)
        return bool(row and row[0] and not row[1])

    # the crew gives the script again, as a copy elsewhere: it is said where it goes on
    (root / "copy.txt").write_text((root / "undo.txt").read_text())
    p = subprocess.Popen(TROLLEY + ["survey", "resume", "t1", "--root", "projects", "--session", "undo",
                                    "--speedup", "40", "--script", "copy.txt"], cwd=root,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 90
    while p.poll() is None and not after_the_last_sample():
        assert time.monotonic() < deadline
    killed = p.poll() is None
    if killed:
        os.kill(p.pid, signal.SIGKILL)
    said = " ".join(p.communicate()[1].split())
    assert "--script copy.txt is not the script this session ran" in said
    assert "the script goes on at its step" in said or "steps were all done before the interruption" in said
    if killed:      # (the resume may have ended the session before the poll saw the edge)
        _resume(root, "undo")
    with ProjectStore.open(root / "projects" / "t1") as st:
        sid = st.session("undo").session_id
        assert st.session("undo").state == "ended"
        fixes = st.fixes(sid)
        undone = st.connection.execute("SELECT COUNT(*) FROM fix_decision WHERE reason LIKE 'undone%'").fetchone()[0]
        stops = st.stops(sid)
    # the undo undid FIX003 only, once
    assert [f.accepted for f in fixes] == [True, True, False] and undone == 1
    assert fixes[2].reason == "undone by the crew"
    # the stops at 0, 60 and 120 m, each once
    assert [s.label for s in stops] == ["S000", "S001", "S002"]
    assert np.allclose([s.chainage_m for s in stops], [0.0, 60.0, 120.0], atol=0.05)
    assert (root / "projects" / "t1" / "sessions" / "undo" / "survey.xlsx").is_file()


@pytest.mark.parametrize("fix_after_the_step", [True, False], ids=["fix-stored-then-killed", "killed-before-the-fix"])
def test_a_scripted_fix_stored_at_the_time_of_the_step_before_is_not_taken_again(tmp_path, fix_after_the_step):
    # (found 2026-11-26) a crew's fix takes no simulated time: the fix of step 2 has the time of
    # step 1's script event, and a kill between the fix and step 2's event made the resume take
    # that fix again (by time, "t_fix > t_step" was false). The script event keeps the newest fix id.
    from types import SimpleNamespace

    from survey.session.fieldsession import FieldSession
    from survey.session.script import parse_script
    from survey.store import FixRecord, ProjectStore, SessionEvent

    make_project(tmp_path)
    with ProjectStore.open(tmp_path / "t1") as st:
        sid = st.create_session("s").session_id
        st.add_fix(sid, FixRecord(100.0, "FIX001", 1.0, 2.0, 3.0, 6e-4, 6e-4, 6e-4))
        stub = SimpleNamespace(config=SimpleNamespace(script=parse_script("fix\nfix\nend\n")), script_index=1,
                               store=st, rec=SimpleNamespace(session_id=sid))
        stub._event = lambda kind, detail: st.add_event(sid, SessionEvent(100.0, kind, detail))
        stub._script_event_detail = lambda: FieldSession._script_event_detail(stub)
        stub._event("script", FieldSession._script_event_detail(stub))        # step 1 done: "1 <id of FIX001>"
        if fix_after_the_step:
            st.add_fix(sid, FixRecord(100.0, "FIX002", 1.0, 2.0, 3.0, 6e-4, 6e-4, 6e-4))
        FieldSession._resume_script_step(stub, st.fixes(sid))
        assert stub.script_index == (2 if fix_after_the_step else 1)
        last = [e for e in st.events(sid) if e.kind == "script"][-1]
        assert last.detail.split()[0] == str(stub.script_index)
