"""A person at the keyboard: the interactive session driven through a real pseudo-terminal (pexpect).

Station setup accepted with ``a``, a fix at the first stop, a note, the static alignment, a fix at the
next stop, undone with ``u`` and taken again, a pause (train) and resume, end with ``e``: the store holds what was typed, and the sheet
is written.
"""
from __future__ import annotations

import json

import io
import os
import sys
import time

import numpy as np
import pexpect

from session_project import make_project


def _start(tmp_path, session: str, speedup: str):
    """A simulated session started at a terminal (pexpect)."""
    env = {**os.environ, "TERM": "xterm", "COLUMNS": "140", "LINES": "50"}
    return pexpect.spawn(sys.executable, ["-m", "survey.cli", "survey", "start", "t1", "--root", "projects",
                                          "--session", session, "--simulate", "--speedup", speedup],
                         cwd=str(tmp_path), env=env, encoding="utf-8", timeout=60, dimensions=(50, 140))


def _end(child) -> None:
    """``e``, confirmed with ``y``: the session ends and writes the sheet."""
    child.send("e")
    child.expect("end the session\\? y = end it")
    child.send("y")
    child.expect("survey sheet:", timeout=90)
    child.expect(pexpect.EOF)


def _fix(child, label: str) -> None:
    """``f`` until the fix ``label`` is accepted (a machine too loaded to stream for 1 s pauses the
    session for a device fault, and the key is answered with that)."""
    for _ in range(20):
        child.send("f")
        if child.expect([f"{label} accepted", "waiting for the devices"]) == 0:
            return
        time.sleep(0.5)
    raise AssertionError(f"{label} not taken")


def _at_the_60_m_stop(tmp_path):
    """A session ``kb`` at 40x: the station accepted, FIX001 at the start, the trolley standing at
    the 60 m stop (its world waits there for the fix)."""
    make_project(tmp_path / "projects", static_s="20.0")
    child = _start(tmp_path, "kb", "40")
    try:
        child.expect("a accept")
        child.send("a")
        child.expect("station accepted")
        _fix(child, "FIX001")
        child.expect("standing at 60")
    except BaseException:
        child.close()
        raise
    return child


def test_interactive_session_with_two_fixes_a_pause_and_a_note(tmp_path):
    make_project(tmp_path / "projects", static_s="20.0", stop_s="30.0")  # 2 s per stop at 15x: time to type
    child = _start(tmp_path, "kb", "15")
    try:
        child.expect("a accept")
        child.send("d")  # drop the point data snooping suggests, see the table again, accept
        child.expect("dropped: CP")
        child.expect("a accept")
        child.send("a")
        child.expect("station accepted")
        child.send("f")
        child.expect("FIX001 accepted")
        child.send("n")
        for ch in "prism ok\r":
            child.send(ch)
        child.expect("note at")
        child.expect("static alignment done")
        child.expect("standing at 60")
        child.send("f")
        child.expect("FIX002 accepted")
        child.send("u")
        child.expect("FIX002 undone")
        child.send("f")
        child.expect("FIX003 accepted")
        child.send("p")
        child.expect("paused")
        child.send("f")  # no fix during a pause: answered, and the next key still works
        child.expect("paused: p to resume first")
        child.send("p")
        child.expect("resumed")
        _end(child)
    finally:
        child.close()
    assert child.exitstatus == 0
    from survey.store import ProjectStore

    with ProjectStore.open(tmp_path / "projects" / "t1") as st:
        sid = st.session("kb").session_id
        fixes = st.fixes(sid)
        assert [(f.point, f.accepted) for f in fixes] == [("FIX001", True), ("FIX002", False), ("FIX003", True)]
        assert fixes[1].reason == "undone by the crew"
        assert [n.text for n in st.notes(sid)] == ["prism ok"]
        kinds = [e.kind for e in st.events(sid)]
        assert kinds.index("pause") < kinds.index("resume") < kinds.index("end")
        assert st.session("kb").state == "ended"
        setup = st.station_setups(sid)[0]
        assert len(setup.excluded) == 1
        assert [o.used for o in st.setup_observations(setup.setup_id)].count(False) == 1
    assert (tmp_path / "projects" / "t1" / "sessions" / "kb" / "survey.xlsx").is_file()


def test_at_40x_the_world_waits_at_every_stop_f_while_moving_is_answered_and_e_asks_first(tmp_path):
    """8 s stops at 40x last 0.2 s of wall-clock time, and the 20 s first stop ends in the tick in
    which the static alignment ends: the simulated world waits at each stop until the crew has
    taken its fix there, however late the key comes (before 2026-11-27 it waited only once the
    session had seen the trolley standing after the alignment: on a loaded machine the trolley had
    left the first stop, ``f`` was answered "the trolley is moving", and CI failed). ``f`` while
    the trolley moves says why nothing happens; ``e`` asks before it ends the session. The last
    stop ends where the simulated data end: ``f`` there takes the fix (it was dropped without a
    word once the world waited at a stop's end: the last interval had no closing fix)."""
    make_project(tmp_path / "projects", static_s="20.0")  # 8 s stops (tests/session_project.py)
    child = _start(tmp_path, "fast", "40")
    try:
        child.expect("a accept")
        child.send("a")
        child.expect("station accepted")
        child.expect("static alignment done: f = take a fix here")
        time.sleep(1.0)  # 40 s of simulated time: twice the first stop, had the world not waited
        _fix(child, "FIX001")
        child.expect("moving")
        child.send("f")
        child.expect("f ignored: the trolley is moving")
        child.expect("standing at 60")
        time.sleep(1.0)  # 40 s of simulated time: five times the stop, had the world not waited
        _fix(child, "FIX002")
        child.send("e")
        child.expect("end the session\\? y = end it")
        child.send("x")
        child.expect("the session goes on")
        # the last stop ends where the simulated data end: the world waits there for the fix, and
        # f takes it (it was dropped without a word, "the simulated survey is over")
        child.expect("standing at 120")
        time.sleep(1.0)
        child.expect("f = take the fix at this last stop")
        child.send("f")
        child.expect("FIX003 accepted", timeout=10)
        _end(child)
    finally:
        child.close()
    assert child.exitstatus == 0
    from survey.commands.survey import simulated_world
    from survey.session.simworld import stop_index_at
    from survey.store import ProjectStore

    with ProjectStore.open(tmp_path / "projects" / "t1") as st:
        fixes = st.fixes(st.session("fast").session_id)
        sim = simulated_world(st, 1.0).sim
    assert [(f.point, f.accepted) for f in fixes] == [("FIX001", True), ("FIX002", True), ("FIX003", True)]
    assert [stop_index_at(sim, f.t_s) for f in fixes] == [0, 1, 2]  # the second one at the 60 m stop


def test_one_set_of_keys_on_the_screen(tmp_path):
    """The screen shows the keys of what the crew is doing now, and only those."""
    from rich.console import Console

    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.screen import KEYS_HELP, render
    from survey.store import FixRecord, ProjectStore

    make_project(tmp_path)
    with ProjectStore.open(tmp_path / "t1") as st:
        fs = FieldSession(st, "keys", SessionConfig(), console=Console(file=io.StringIO()))

        def shown():
            fs.screen.prompt = fs.keys_prompt()
            out = io.StringIO()
            Console(file=out, width=200).print(render(fs.screen))
            text = out.getvalue()
            return [p for p in ("f fix |", "a accept | d drop", "r measure again", "end the session?",
                                "p resume", "note:") if p in text]

        assert fs.keys_prompt() == KEYS_HELP and shown() == ["f fix |"]
        fs._key_prompt = "a accept | d drop CP0003L | m measure again"
        assert shown() == ["a accept | d drop"]
        fs._key_prompt = ""
        fs.pending = (1, FixRecord(0.0, "FIX002", 0.0, 0.0, 0.0, 1e-3, 1e-3, 1e-3), None)
        assert shown() == ["r measure again"]
        fs.pending, fs.paused = None, True
        assert shown() == ["p resume"]
        fs.paused, fs._confirm_end = False, True
        assert shown() == ["end the session?"]
        fs._confirm_end, fs.note_buffer = False, "rail"
        assert shown() == ["note:"]


def test_an_ended_session_is_reopened_to_add_intervals(tmp_path):
    """The crew ends at the 60 m stop before its fix (``e``, ``y``: one fix, nothing to process);
    ``trolley survey resume --reopen`` continues the session with a script: the fix at 60 m, the
    next interval, the fix at 120 m. The session is processed again at its new end."""
    import subprocess

    child = _at_the_60_m_stop(tmp_path)
    try:
        child.send("e")
        child.expect("end the session\\? y = end it")
        child.send("y")
        child.expect("fewer than two accepted fixes: nothing to process", timeout=90)
        child.expect(pexpect.EOF)
    finally:
        child.close()
    assert child.exitstatus == 0
    args = [sys.executable, "-m", "survey.cli", "survey", "resume", "t1", "--root", "projects", "--session", "kb"]
    (tmp_path / "add.txt").write_text("fix\nmove\nfix\nend\n")
    r = subprocess.run(args + ["--reopen", "--script", "add.txt"], cwd=tmp_path, capture_output=True, text=True,
                       timeout=300, env={**os.environ, "COLUMNS": "160"})
    assert r.returncode == 0, r.stderr[-3000:]
    from survey.commands.survey import simulated_world
    from survey.session.simworld import stop_index_at
    from survey.store import ProjectStore

    with ProjectStore.open(tmp_path / "projects" / "t1") as st:
        sid = st.session("kb").session_id
        fixes = st.fixes(sid)
        sim = simulated_world(st, 1.0).sim
        kinds = [e.kind for e in st.events(sid)]
        # the reopen's script is kept: a kill during it resumes with it, without --script again
        kept = [json.loads(e.detail) for e in st.events(sid) if e.kind == "script_file"]
        finals = [p for p in st.processing_runs(sid) if p.kind == "final"]
        track = st.track(finals[-1].run_id)
        assert st.session("kb").state == "ended"
    assert [(f.point, f.accepted) for f in fixes] == [("FIX001", True), ("FIX002", True), ("FIX003", True)]
    assert [stop_index_at(sim, f.t_s) for f in fixes] == [0, 1, 2]
    assert kinds.count("end") == 2 and kinds.index("reopened") < kinds.index("resumed")
    assert kept == [{"script": str((tmp_path / "add.txt").resolve())}]
    assert kinds.index("reopened") < kinds.index("script_file")
    assert kinds.count("interval") == 2  # the live summaries of the two intervals added
    assert len(finals) == 1 and track.chainage_m[0] < 1.0 and track.chainage_m[-1] > 119.0
    assert "survey.xlsx" in r.stdout


def test_killed_at_a_stop_the_interactive_resume_finds_the_trolley_still_there(tmp_path):
    """kill -9 while the world waits at the 60 m stop for its fix; ``trolley survey resume`` at the
    keyboard: the device check and the restore take wall-clock time, 40-120 simulated s at 40x,
    in which the world had left the stop before the loop held it (``f`` was answered "the
    trolley is moving"). The world now stands at the stop's end from its start until the loop
    looks, and the fix taken 2 s (80 simulated s) later is the 60 m stop's."""
    import signal

    child = _at_the_60_m_stop(tmp_path)
    try:
        time.sleep(1.5)  # the world waits at the stop's end; the store has the data up to it (0.5 s flushes)
        os.kill(child.pid, signal.SIGKILL)
    finally:
        child.close()
    env = {**os.environ, "TERM": "xterm", "COLUMNS": "140", "LINES": "50"}
    child = pexpect.spawn(sys.executable, ["-m", "survey.cli", "survey", "resume", "t1", "--root", "projects",
                                           "--session", "kb"], cwd=str(tmp_path), env=env, encoding="utf-8",
                          timeout=60, dimensions=(50, 140))
    try:
        child.expect("f fix")
        time.sleep(2.0)
        _fix(child, "FIX002")
    finally:
        child.terminate(force=True)
    from survey.commands.survey import simulated_world
    from survey.session.simworld import stop_index_at
    from survey.store import ProjectStore

    with ProjectStore.open(tmp_path / "projects" / "t1") as st:
        fixes = st.fixes(st.session("kb").session_id)
        sim = simulated_world(st, 1.0).sim
    assert [(f.point, f.accepted, stop_index_at(sim, f.t_s)) for f in fixes] == [("FIX001", True, 0),
                                                                                ("FIX002", True, 1)]


def test_killed_again_and_again_at_a_stop_the_resumed_world_still_waits_there():
    """Each interactive resume at a stop's end sends 0.1 s more data (the device check waits for
    a sample of every stream); the stop is left only once the trolley has moved from it. By time
    alone (the stop's end + 0.1 s) the third kill at the 60 m stop, with data stored to 0.2 s past
    its end, found the world heading for the 120 m stop: the fix at 60 m was lost."""
    from types import SimpleNamespace

    from survey.session.fieldsession import HELD_MOVE_M, FieldSession
    from survey.session.simworld import SimClock
    from trolley.truthsim import motion_profile

    m = motion_profile(0.0, 120.0, 60.0, static_s=20.0, stop_s=8.0, speed_m_s=2.0, accel_time_s=4.0)
    fs = FieldSession.__new__(FieldSession)
    end = float(m.stop_end_s[1])
    stored, limits = end, []
    for _ in range(4):   # killed at the limit each time, resumed at the keyboard
        fs._hold_ends = {}
        fs.world = SimpleNamespace(sim=SimpleNamespace(truth=SimpleNamespace(motion=m)), clock=SimClock(stored, 40.0))
        fs._hold_before_loop(stored)
        stored = fs.world.clock.limit
        limits.append(round(stored - end, 6))
    # 5 um, 0.08 mm, 0.41 mm from the stop: standing; the fourth resume would send the trolley
    # 1.3 mm on, and the world goes on to the next stop's end (the 120 m stop, the data's end)
    assert limits == [0.1, 0.2, 0.3, round(float(m.stop_end_s[2]) - end, 6)]
    moved = m.evaluate(np.array([end, end + 0.3]))[0]
    assert abs(moved[1] - moved[0]) <= HELD_MOVE_M


def test_at_40x_a_station_change_right_after_a_fix_has_the_trolley_at_its_stop(tmp_path):
    """``f`` then ``s`` at the 60 m stop: the world stays there 2 s after the fix (CREW_LINGER_S),
    so the station change finds the trolley standing and measures the overlap at that stop
    (before, at 40x, the trolley left in the next tick: "station change: stop the trolley first")."""
    child = _at_the_60_m_stop(tmp_path)
    try:
        _fix(child, "FIX002")
        child.expect("moves on in 2 s")
        time.sleep(0.5)  # the crew reads the screen: 20 simulated s at 40x
        child.send("s")
        child.expect("station change: setting up station 2")
        child.expect("a accept")
        child.send("a")
        child.expect("overlap check at FIX002: new - old station")
        child.expect("overlap fix FIX003 accepted")
    finally:
        child.terminate(force=True)
