"""The static alignment restarts when the trolley moves, and the final processing starts there."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from rich.console import Console

from session_project import make_project


@pytest.mark.slow  # 7 s; the session tests' budget is spent on the required ones
def test_alignment_restarts_when_the_trolley_moves(tmp_path):
    from survey.commands.survey import simulated_world
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore

    # the simulated trolley leaves after 10 s, but the session aligns for 30 s: it must restart and
    # align at the first stop (60 m, reached at 44 s, 40 s long)
    make_project(tmp_path, static_s="10.0", stop_s="40.0")
    console = Console(stderr=True, record=True, width=150)
    with ProjectStore.open(tmp_path / "t1") as st:
        world = simulated_world(st, 50.0)
        world.sim.session.meta = replace(world.sim.session.meta, static_s=30.0)
        fs = FieldSession(st, "realign", SessionConfig(script=parse_script("wait 50\nfix\nmove\nfix\nend\n"),
                                                        out_dir=tmp_path / "out"), world=world, console=console)
        out = fs.run()
        events = st.events(fs.rec.session_id)
        kinds = [e.kind for e in events]
        assert "alignment_restart" in kinds
        aligned = json.loads(next(e.detail for e in events if e.kind == "aligned"))
        m = world.sim.truth.motion
        # the restart is one second after the trolley was seen moving, then the last restart is when
        # it stood still again at the first stop
        assert m.stop_start_s[1] - 0.5 < aligned["static_start_s"] < m.stop_start_s[1] + 2.5
        assert aligned["static_s"] == 30.0
        assert out.fixes_accepted == 2 and out.xlsx is not None and out.xlsx.is_file()
        # the final processing used the data from the restarted alignment on
        from survey.sessionio import read_session

        raw = read_session(tmp_path / "out" / "session")
        assert raw.imu_t_s[0] >= aligned["static_start_s"] - 1e-9
        track = out.result.stations
        assert np.nanmin(track.chainage_m) > 55.0  # the survey starts at the first stop
    assert "static alignment restarts" in console.export_text()


def test_the_total_stations_noise_follows_the_simulations_seed(tmp_path):
    # a survey of another seed is another realisation of the fixes too (the total station's noise
    # was seeded 7 for every seed); the default seed 0 keeps 7, and with it the demo's figures
    from survey.commands.survey import simulated_world
    from survey.session.simworld import SimOptions
    from survey.store import ProjectStore

    make_project(tmp_path, seed="3")
    with ProjectStore.open(tmp_path / "t1") as st:
        world = simulated_world(st, 50.0)
    assert SimOptions.seed == 7 and world.options.seed == 10
