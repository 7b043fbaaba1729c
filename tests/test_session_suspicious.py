"""A suspicious fix (a blunder of the simulated total station fails the innovation test): the crew
measures again or accepts it, by script and by key. After each accepted closing fix the interval
behind it is summarised (with its defects line) and stored (an "interval" processing run and event
with the seconds it took; the benchmark measures the speed)."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
from rich.console import Console

from session_project import make_project

#: stop 2 (120 m), first attempt: 30 mm east; stop 3 (180 m), first attempt: 25 mm up. Not at stop 1:
#: the first interval's heading comes from the static alignment alone, and the live filter's
#: prediction there is decimetres uncertain (a blunder of centimetres passes, rightly)
BLUNDERS = ((2, 0, 0.030, 0.0, 0.0), (3, 0, 0.0, 0.0, 0.025))
EXPECTED = [("FIX001", True, "accepted"), ("FIX002", True, "accepted"), ("FIX003", False, "rejected: measured again"),
            ("FIX004", True, "accepted"), ("FIX005", True, "accepted by the crew despite the innovation test")]


def _run(tmp_path, name, speedup, script=None, keys=None, **simulation):
    from survey.commands.survey import simulated_world
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore

    make_project(tmp_path, **simulation)
    console = Console(stderr=True, record=True, width=400)
    with ProjectStore.open(tmp_path / "t1") as st:
        world = simulated_world(st, speedup)
        world.options = replace(world.options, fix_blunders_m=BLUNDERS)
        fs = FieldSession(st, name, SessionConfig(script=parse_script(script) if script else None, out_dir=None),
                          world=world, console=console, keys=keys)
        if keys is not None:
            keys.fs = fs
        fs.run()
        sid = fs.rec.session_id
        fixes = [(f.point, f.accepted, f.reason) for f in st.fixes(sid)]
        events = [json.loads(e.detail) for e in st.events(sid) if e.kind == "interval"]
        runs = [r for r in st.processing_runs(sid) if r.kind == "interval"]
        tracks = [st.track(r.run_id) for r in runs]
    return fs, " ".join(console.export_text().split()), fixes, events, runs, tracks


def _check(fs, text, fixes, events, runs, tracks):
    assert [f[:2] for f in fixes] == [f[:2] for f in EXPECTED]
    assert [f[2] for f in fixes] == [f[2] for f in EXPECTED]
    # the blunder is explained: innovation per axis in mm (30 mm east, plus the dead reckoning's own
    # error over the 60 m after a 20 s alignment: 5.0 mm on one run), NIS and the gate
    i = text.index("suspicious fix FIX003: innovation E ")
    assert 20.0 < abs(float(text[i + len("suspicious fix FIX003: innovation E "):].split()[0])) < 40.0
    assert "NIS" in text and "r = measure again, a = accept anyway" in text
    h = text.index("suspicious fix FIX005: innovation E ")
    assert 20.0 < abs(float(text[h:].split(" H ")[1].split()[0])) < 30.0  # 25 mm up
    # one summary per interval, after the fix that closed it, with its defects line
    assert len(events) == 3 and len(runs) == 3 and all(len(t) > 20 for t in tracks)
    for fix, ev in zip(("FIX002", "FIX004", "FIX005"), events):
        assert text.index(f"fix {fix} accepted") < text.index(" ".join(ev["summary"].split()[:4]))
    for ev, run, tr in zip(events, runs, tracks):
        assert ev["run_id"] == run.run_id and (run.t_start_s, run.t_end_s) == (ev["t_start_s"], ev["t_end_s"])
        assert 0.0 < ev["seconds"] < 1.0  # stored as measured (the benchmark measures the speed)
        assert f"({ev['seconds']:.2f} s)" in ev["summary"]
        assert "gauge " in ev["summary"] and "cant " in ev["summary"] and ".." in ev["summary"]
        assert f"against {ev['tolerances']}" in ev["summary"]  # the defects line
        assert ev["summary"].split("max |lateral| ")[0] in text  # shown to the crew
        g = [float(x) for x in ev["summary"].split("gauge ")[1].split(" mm")[0].split("..")]
        assert abs(g[0] - 1e3 * np.nanmin(tr.gauge_m)) < 0.006 and abs(g[1] - 1e3 * np.nanmax(tr.gauge_m)) < 0.006
    assert np.all(np.diff([t.chainage_m[0] for t in tracks]) > 50.0)  # consecutive intervals
    assert len(fs.interval_seconds) == 3


def test_suspicious_fixes_remeasured_and_accepted_by_script(tmp_path):
    script = "fix\nmove\nfix\nmove\nfix\nremeasure\nmove\nfix\naccept\nend\n"
    _check(*_run(tmp_path, "scripted", 25.0, script=script, length_m="180.0"))


class Crew:
    """Keys as a person presses them, each when the screen shows the moment for it."""

    def __init__(self) -> None:
        self.fs = None
        self.step = 0

    def _at_next_stop(self, n_fixes: int) -> bool:
        fs = self.fs
        return (len(fs.accepted_fixes) == n_fixes and fs.aligned and fs.stop_started_s is not None
                and fs.screen.distance_since_fix_m > 50.0)

    def get(self) -> str | None:
        fs = self.fs
        plan = [(lambda: True, "a"),  # accept the free station
                (lambda: fs.setup_id is not None, "f"),  # FIX001 at the first stop
                (lambda: self._at_next_stop(1), "f"),  # FIX002
                (lambda: self._at_next_stop(2), "f"),  # FIX003: suspicious
                (lambda: fs.pending is not None, "r"),  # FIX004
                (lambda: self._at_next_stop(3), "f"),  # FIX005: suspicious
                (lambda: fs.pending is not None, "a"),
                (lambda: len(fs.interval_seconds) == 3, "e"),
                (lambda: fs._confirm_end, "y")]  # e asks before it ends the session
        if self.step < len(plan) and plan[self.step][0]():
            self.step += 1
            return plan[self.step - 1][1]
        return None


def test_suspicious_fixes_remeasured_and_accepted_by_key(tmp_path):
    _check(*_run(tmp_path, "keys", 15.0, keys=Crew(), length_m="180.0", static_s="20.0", stop_s="30.0"))


def test_the_final_processing_keeps_the_fix_the_crew_accepted(tmp_path):
    # FIX005 (25 mm up) failed the live test and the crew accepted it anyway: the engine's gate and
    # its data snooping would reject it again in the final processing, which must not overrule them
    import pandas as pd

    from survey.commands.survey import simulated_world
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore

    make_project(tmp_path, length_m="180.0")
    script = "fix\nmove\nfix\nmove\nfix\nremeasure\nmove\nfix\naccept\nend\n"
    with ProjectStore.open(tmp_path / "t1") as st:
        world = simulated_world(st, 25.0)
        world.options = replace(world.options, fix_blunders_m=BLUNDERS)
        FieldSession(st, "final", SessionConfig(script=parse_script(script), out_dir=tmp_path / "out"),
                     world=world, console=Console(stderr=True, width=200)).run()
    fixes = pd.read_csv(next((tmp_path / "out").rglob("processed/fixes.csv")), keep_default_na=False)
    row = fixes[fixes.point == "FIX005"].iloc[0]
    assert row.accepted == 1 and row.nis > 21.1
    assert row.reason == "accepted by the crew despite the gate"
    assert "FIX003" not in set(fixes.point)  # measured again: not in the session the engine sees
