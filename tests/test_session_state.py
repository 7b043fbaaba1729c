"""Crew state of a field session without devices: undo restores the chainage reference, and a
suspicious fix left undecided by a crash is offered again on resume (then accepted by the script)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from rich.console import Console

from session_project import make_project


def _session(st, name, script=None, resume=False):
    from survey.session.acquisition import Acquisition, TimeBase
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script

    console = Console(stderr=True, record=True, width=160)
    fs = FieldSession(st, name, SessionConfig(script=parse_script(script) if script else None, live=False),
                      console=console, resume=resume)
    fs.open_session()
    fs.acq = Acquisition({}, None, TimeBase())  # no ports: the buffers hold a straight 0..130 m push
    t = np.arange(0.0, 130.0, 0.01)
    fs.acq.buffers.add("odo", np.column_stack([t, np.clip(t - 5.0, 0.0, 120.0)]))
    return fs, console


def _design_point(fs, chainage_m):
    p = fs._design.evaluate(np.array([chainage_m]))
    return float(p.E_m[0]), float(p.N_m[0]), float(p.H_m[0])


def test_undo_counts_chainage_and_distance_from_the_previous_fix_again(tmp_path):
    from survey.store import FixRecord, ProjectStore

    make_project(tmp_path)
    with ProjectStore.open(tmp_path / "t1") as st:
        fs, _ = _session(st, "u")
        s0 = fs._design.start_chainage_m
        fixes = []
        for t, d in ((4.0, 0.0), (70.0, 60.0)):
            f = FixRecord(t, f"FIX{len(fixes) + 1:03d}", *_design_point(fs, s0 + 10.0 + d), 6e-4, 6e-4, 6e-4)
            f = replace(f, fix_id=st.add_fix(fs.rec.session_id, f))
            fs._accepted(f, d)
            fixes.append(f)
        assert abs(fs.chainage_now(60.0) - (s0 + 70.0)) < 1e-3
        fs.undo_last_fix()
        # back to the first fix: 60 m of odometer since it, chainage counted from its projection
        assert fs.last_fix == fixes[0] and fs.last_fix_distance_m == 0.0
        assert abs(fs.last_fix_chainage_m - (s0 + 10.0)) < 1e-6
        assert abs(fs.chainage_now(60.0) - (s0 + 70.0)) < 1e-3
        fs.undo_last_fix()
        assert fs.last_fix is None and np.isnan(fs.chainage_now(60.0))
        assert [(f.point, f.accepted, f.reason) for f in st.fixes(fs.rec.session_id)] == [
            ("FIX001", False, "undone by the crew"), ("FIX002", False, "undone by the crew")]


def test_a_suspicious_fix_is_offered_again_after_a_crash(tmp_path):
    from survey.session.script import Action
    from survey.store import FixRecord, ProjectStore, SessionEvent

    make_project(tmp_path)
    script = "fix\nmove\nfix\naccept\nend\n"
    with ProjectStore.open(tmp_path / "t1") as st:
        fs, _ = _session(st, "p", script)
        sid = fs.rec.session_id
        s0 = fs._design.start_chainage_m
        f1 = FixRecord(4.0, "FIX001", *_design_point(fs, s0 + 10.0), 6e-4, 6e-4, 6e-4, reason="accepted")
        st.add_fix(sid, f1)
        for i in (1, 2):  # fix and move done
            st.add_event(sid, SessionEvent(float(i), "script", str(i)))
        f2 = FixRecord(70.0, "FIX002", *_design_point(fs, s0 + 70.03), 6e-4, 6e-4, 6e-4, accepted=False,
                       reason="innovation test failed: NIS 52.1 > 21.1")
        st.add_fix(sid, f2)
        # ... the process dies before the crew answers
    with ProjectStore.open(tmp_path / "t1") as st:
        fs, console = _session(st, "p", script, resume=True)
        fs.restore()
        assert fs.pending is not None and fs.pending[1].point == "FIX002"
        assert fs.last_fix.point == "FIX001" and fs.script_index == 3  # the stored fix was the step "fix"
        assert "suspicious fix FIX002 still to decide" in console.export_text()
        assert fs._next_action() == Action("accept", line=4)
        assert fs.do(fs._next_action())
        assert fs.pending is None and fs.last_fix.point == "FIX002"
        assert abs(fs.last_fix_distance_m - 65.0) < 1e-9  # the odometer at the fix time (70 s - 5 s)
        got = [(f.point, f.accepted, f.reason) for f in st.fixes(fs.rec.session_id)]
        assert got == [("FIX001", True, "accepted"),
                       ("FIX002", True, "accepted by the crew despite the innovation test")]
