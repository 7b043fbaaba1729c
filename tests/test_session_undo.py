"""The crew's undo of a fix that closed an interval: the live summary of that interval (its
``interval`` event and processing run) is withdrawn with the undo, and the fix taken again closes
the interval and summarises it anew; also when the session is killed with SIGKILL after the undo
and resumed (bug hunt: the summary of the undone fix stayed stored and on the screen, and a resume
took the summary of the undone fix, which has the times of the fix taken again at the same stop,
for the summary of the new one and never summarised it)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from rich.console import Console

from polling import count_in_store
from session_project import make_project

TROLLEY = [sys.executable, "-m", "survey.cli"]
#: the fix at 60 m undone and taken again at the same stop (in the same simulated instant)
AGAIN = "fix\nmove\nfix\nundo\nfix\nmove\nfix\nend\n"
#: the fix at 120 m undone, and the session ended without it
LAST = "fix\nmove\nfix\nmove\nfix\nundo\nend\n"


def _summaries(st, sid):
    """(the runs of kind "interval", the summaries (``interval`` events) of those runs, all
    ``interval`` events, the ``interval_undone`` events, the event kinds in order)."""
    events = st.events(sid)
    runs = [r for r in st.processing_runs(sid) if r.kind == "interval"]
    intervals = [json.loads(e.detail) for e in events if e.kind == "interval"]
    standing = [d for d in intervals if d["run_id"] in {r.run_id for r in runs}]
    withdrawn = [json.loads(e.detail) for e in events if e.kind == "interval_undone"]
    return runs, standing, intervals, withdrawn, [e.kind for e in events]


@pytest.mark.parametrize("script, accepted", [(AGAIN, [True, False, True, True]), (LAST, [True, True, False])],
                         ids=["taken-again", "last-fix"])
def test_an_undone_fix_takes_the_summary_of_its_interval_with_it(tmp_path, script, accepted):
    from survey.commands.survey import simulated_world
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore

    make_project(tmp_path)
    console = Console(stderr=True, record=True, width=400)
    with ProjectStore.open(tmp_path / "t1") as st:
        fs = FieldSession(st, "u", SessionConfig(script=parse_script(script), out_dir=None),
                          world=simulated_world(st, 40.0), console=console)
        fs.run()
        sid = fs.rec.session_id
        fixes = st.fixes(sid)
        runs, standing, intervals, withdrawn, kinds = _summaries(st, sid)
        undone_runs = [r for r in st.processing_runs(sid) if r.kind == "interval_undone"]
        text = " ".join(console.export_text().split())
        assert [f.accepted for f in fixes] == accepted
        good = [f for f in fixes if f.accepted]
        undone = next(f for f in fixes if not f.accepted)
        # the summaries that stand are those of the intervals between consecutive accepted fixes,
        # each with its run; the one the undone fix closed is kept as withdrawn (the crew saw it)
        assert [(r.t_start_s, r.t_end_s) for r in runs] == [(a.t_s, b.t_s) for a, b in zip(good, good[1:])]
        assert [d["run_id"] for d in standing] == [r.run_id for r in runs]
        assert len(intervals) == len(runs) + 1 and len(undone_runs) == 1
        assert withdrawn == [{"run_id": undone_runs[0].run_id, "fix_id": undone.fix_id}]
        # withdrawn with the undo (one transaction: the withdrawal right after the undo event)
        assert kinds[kinds.index("undo") + 1] == "interval_undone"
        assert f"fix {undone.point} undone; the summary of its interval is withdrawn" in text
        if script == AGAIN:
            # the fix taken again at the stop closed the interval again, at the same times as the
            # undone one, and summarised it after the undo
            assert undone.t_s == good[1].t_s
            assert kinds.index("undo") < [i for i, k in enumerate(kinds) if k == "interval"][1]
            assert [d["summary"].split(":")[0] for d in standing] == ["interval 0.0-60.0 m", "interval 60.0-120.0 m"]
        else:
            # the screen no longer shows the summary of the interval that is open again
            assert fs.screen.last_interval == ""
            assert [d["summary"].split(":")[0] for d in standing] == ["interval 0.0-60.0 m"]
        assert st.interval_summaries(sid) == standing


def _survey(*args: str) -> list[str]:
    return TROLLEY + ["survey", *args, "t1", "--root", "projects", "--speedup", "40"]


def _run(root, *args: str) -> None:
    r = subprocess.run(_survey(*args), cwd=root, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]


def test_killed_after_the_undo_and_the_fix_taken_again_the_resume_summarises_the_interval(tmp_path):
    """Killed once the fix taken again is stored: its summary is computed on a thread and stored at
    the next refresh, so the kill comes before it (a later kill makes the test pass without
    testing it, never fail). The resume summarises the interval that fix closed, as the
    uninterrupted run does."""
    from survey.store import ProjectStore

    make_project(tmp_path / "projects")
    (tmp_path / "crew.txt").write_text(AGAIN)
    _run(tmp_path, "start", "--session", "ref", "--simulate", "--script", "crew.txt")
    db = tmp_path / "projects" / "t1" / "project.sqlite"
    p = subprocess.Popen(_survey("start", "--session", "cut", "--simulate", "--script", "crew.txt"), cwd=tmp_path,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    third = ("SELECT COUNT(*) FROM fix f JOIN session s ON s.id = f.session_id WHERE s.name = 'cut'")
    deadline = time.monotonic() + 90
    while count_in_store(db, third) < 3:
        assert p.poll() is None and time.monotonic() < deadline
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    _run(tmp_path, "resume", "--session", "cut")
    with ProjectStore.open(tmp_path / "projects" / "t1") as st:
        out, standing = {}, {}
        for name in ("ref", "cut"):
            sid = st.session(name).session_id
            fixes = st.fixes(sid)
            runs, standing[name], intervals, withdrawn, kinds = _summaries(st, sid)
            undo = kinds.index("undo")
            good = [f for f in fixes if f.accepted]
            out[name] = ([f.accepted for f in fixes], [d["summary"].split(":")[0] for d in standing[name]],
                         len(withdrawn), sum(k == "interval" for k in kinds[undo:]),
                         [(r.t_start_s, r.t_end_s) for r in runs] == [(a.t_s, b.t_s) for a, b in zip(good, good[1:])])
        # the same fixes, one summary withdrawn, both intervals summarised after the undo, and the
        # interval runs are those of the accepted fixes
        assert out["cut"] == out["ref"] == ([True, False, True, True],
                                            ["interval 0.0-60.0 m", "interval 60.0-120.0 m"], 1, 2, True)
        for name in ("ref", "cut"):
            assert st.interval_summaries(st.session(name).session_id) == standing[name]
