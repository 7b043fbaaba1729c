"""A train: the crew pauses the session, lifts the trolley off the track and puts it back 3 cm
further along (the odometer does not see it), resumes and takes a fix. The processing finds the
handling in the IMU data and lets the fix after it re-anchor the position: every fix is accepted
and the final track stays within its sigmas."""
from __future__ import annotations

import numpy as np
from rich.console import Console

from session_project import make_project

#: stop 1 lasts 24 s; the crew holds the trolley off the track from 9 s to 15 s into it
SIM = {"length_m": "120.0", "stop_s": "24.0"}
SCRIPT = "fix\nmove\nfix\npause\nwait 18\nresume\nfix\nmove\nfix\nend\n"


def test_trolley_lifted_off_for_a_train(tmp_path):
    from survey.commands.survey import simulated_world
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore

    folder = make_project(tmp_path, **SIM)
    toml = folder / "project.toml"
    toml.write_text(toml.read_text(encoding="utf-8").replace(
        "[simulation]\n", "[simulation]\nlift_at_stops = [1]\nturn_s = 6.0\nplacement_offset_m = 0.03\n"),
        encoding="utf-8")
    console = Console(stderr=True, record=True, width=400)
    with ProjectStore.open(tmp_path / "t1") as st:
        world = simulated_world(st, 20.0)
        motion = world.sim.truth.motion
        fs = FieldSession(st, "lifted", SessionConfig(script=parse_script(SCRIPT), out_dir=tmp_path / "out"),
                          world=world, console=console)
        fs.run()
        sid = fs.rec.session_id
        fixes = st.fixes(sid)
        events = [e.kind for e in st.events(sid)]
        run = [r for r in st.processing_runs(sid) if r.kind == "final"][-1]
        track = st.track(run.run_id)
        truth = world.sim.truth
    assert "pause" in events and "resume" in events
    assert [f.accepted for f in fixes] == [True] * 4, [(f.point, f.reason) for f in fixes]
    before, after = fixes[1], fixes[2]
    t0 = motion.handling_start_s[0]
    assert before.t_s < t0 < t0 + 6.0 < after.t_s
    # the prism really moved 3 cm along the track between the two fixes at this stop
    assert abs(np.hypot(after.e_m - before.e_m, after.n_m - before.n_m) - 0.03) < 0.003
    # the final track against the truth, within 4 sigma everywhere
    true = truth.at_chainage(track.chainage_m)
    lat = track.lateral_dev_m - true.lateral_m
    psi = true.yaw_rad  # the lateral direction is (cos psi, -sin psi) in E, N
    sig = np.sqrt((np.cos(psi) * track.sigma_enh_m[:, 0]) ** 2 + (np.sin(psi) * track.sigma_enh_m[:, 1]) ** 2)
    assert np.nanmax(np.abs(lat) / sig) < 4.0
    assert np.nanmax(np.abs(track.vertical_dev_m - true.vertical_m) / track.sigma_enh_m[:, 2]) < 4.0
