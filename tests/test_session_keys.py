"""A person at the keyboard: the interactive session driven through a real pseudo-terminal (pexpect).

Station setup accepted with ``a``, a fix at the first stop, a note, the static alignment, a fix at the
next stop, undone with ``u`` and taken again, a pause (train) and resume, end with ``e``: the store holds what was typed, and the sheet
is written.
"""
from __future__ import annotations

import os
import sys

import pexpect

from session_project import make_project


def test_interactive_session_with_two_fixes_a_pause_and_a_note(tmp_path):
    make_project(tmp_path / "projects", static_s="20.0", stop_s="30.0")  # 2 s per stop at 15x: time to type
    env = {**os.environ, "TERM": "xterm", "COLUMNS": "140", "LINES": "50"}
    child = pexpect.spawn(sys.executable, ["-m", "survey.cli", "survey", "start", "t1", "--root", "projects",
                                           "--session", "kb", "--simulate", "--speedup", "15"],
                          cwd=str(tmp_path), env=env, encoding="utf-8", timeout=60, dimensions=(50, 140))
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
        child.send("e")
        child.expect("survey sheet:", timeout=90)
        child.expect(pexpect.EOF)
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
