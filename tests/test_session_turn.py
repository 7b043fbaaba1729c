"""The crew turns the trolley around at a stop (key ``t`` / script ``turn``): the simulated world
turns it (the gyros see the half turn, the odometer then counts down), the chainage shown keeps
increasing, the fix after the turn agrees with the one before it (the lever arm turns with the
trolley), and the final track's cant keeps its sign (left rail higher > 0)."""
from __future__ import annotations

import numpy as np
from rich.console import Console

from session_project import make_project

#: in the 3000 m curve with 120 mm cant (chainage 400-520); stop 1 lasts 24 s; the world turns the
#: trolley from 9 s to 15 s into it (turn_s = 6); the crew's fix comes about 1 s into the stop, the
#: next 18 s later: well inside the standstill after the turn (15 s to 24 s)
SIM = {"length_m": "120.0", "stop_s": "24.0", "prism_lever_arm_m": "[0.0, 0.3, -0.6]"}
SCRIPT = "fix\nmove\nfix\nwait 18\nturn\nfix\nmove\nnote after the turn\nfix\nend\n"


def test_turned_trolley_session(tmp_path):
    from survey.commands.survey import simulated_world
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore

    folder = make_project(tmp_path, **SIM)
    toml = folder / "project.toml"
    toml.write_text(toml.read_text(encoding="utf-8").replace(
        "[simulation]\n", "[simulation]\nstart_chainage_m = 400.0\nturn_at_stops = [1]\nturn_s = 6.0\n"), encoding="utf-8")
    console = Console(stderr=True, record=True, width=400)
    with ProjectStore.open(tmp_path / "t1") as st:
        world = simulated_world(st, 20.0)
        motion = world.sim.truth.motion
        assert motion.turn_start_s.size == 1
        fs = FieldSession(st, "turned", SessionConfig(script=parse_script(SCRIPT), out_dir=tmp_path / "out"),
                          world=world, console=console)
        fs.run()
        sid = fs.rec.session_id
        fixes = st.fixes(sid)
        notes = st.notes(sid)
        run = [r for r in st.processing_runs(sid) if r.kind == "final"][-1]
        track = st.track(run.run_id)
        truth = world.sim.truth
    text = " ".join(console.export_text().split())
    assert "trolley turned around" in text
    assert [f.accepted for f in fixes] == [True] * 4, [(f.point, f.reason) for f in fixes]
    # the two fixes at the turn stop: before and after the turn, the same prism place to the fix
    # noise, the lever arm 0.3 m to the side turned with the trolley (0.6 m apart)
    before, after = fixes[1], fixes[2]
    assert before.t_s < motion.turn_start_s[0] < motion.turn_start_s[0] + 6.0 < after.t_s
    moved = np.hypot(after.e_m - before.e_m, after.n_m - before.n_m)
    assert abs(moved - 0.6) < 0.005
    # the note after the turn and the next move: at the second stop, 520 m (not 460 - 60 = 400)
    assert abs(notes[0].chainage_m - 520.0) < 0.5, notes[0].chainage_m
    # the final track: cant against the truth at each station (a turned trolley's roll taken as
    # the cant would be off by twice the cant: 0.24 m in the canted curve)
    true = truth.at_chainage(track.chainage_m)
    ok = np.isfinite(track.cant_m)
    assert ok.sum() > 150 and np.min(np.abs(true.cant_m)) > 0.1  # in the curve with 120 mm cant
    assert np.max(np.abs(track.cant_m[ok] - true.cant_m[ok])) < 1e-3
    assert np.all(np.diff(track.chainage_m) > 0)
    # the sheet names the project and the session (not the folders they were written to)
    from openpyxl import load_workbook

    wb = load_workbook(tmp_path / "out" / "survey.xlsx", read_only=True)
    head = {r[0]: r[1] for r in wb["Summary"].iter_rows(min_row=1, max_row=6, values_only=True) if r and r[0]}
    wb.close()
    assert head["Project"] == "t1" and head["Session"] == "turned"
