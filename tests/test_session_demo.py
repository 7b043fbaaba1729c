"""``trolley demo`` end to end: the scripted field session on projects/demo (slow: about a minute)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import time

import pytest


@pytest.mark.slow
def test_demo_runs_the_field_session_under_two_minutes(tmp_path):
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "survey.cli", "demo", "--out", str(tmp_path / "out")],
                       capture_output=True, text=True, timeout=300, env={**os.environ, "COLUMNS": "200",
                                                                         "MPLBACKEND": "Agg"})
    wall = time.monotonic() - t0
    assert r.returncode == 0, r.stderr[-3000:]
    out = " ".join(r.stdout.split())
    m = re.search(r"RMS lateral ([\d.]+) mm, vertical ([\d.]+) mm, longitudinal ([\d.]+) mm", out)
    assert m, out
    lateral, vertical, longitudinal = map(float, m.groups())
    assert lateral < 1.0 and vertical < 1.0 and longitudinal < 1.0
    assert "session demo: 2" in out  # 21 stops + overlap checks
    for name in ("survey.xlsx", "processed/track.csv", "crew_script.txt", "project/demo/project.sqlite"):
        assert (tmp_path / "out" / name).exists(), name
    assert wall < 120.0



def test_the_demos_field_session_writes_into_the_demos_own_folder_and_again(tmp_path):
    # `trolley demo`'s field session (demo_session) on a short copy of the demo project: its out
    # folder holds the demo's project and crew script, so the field session must write there (a
    # guard for survey start's own output folders broke exactly this once, and only the slow test
    # above ran the demo)
    import io

    from rich.console import Console
    from session_project import make_project

    from survey.commands.demo import demo_session

    project = make_project(tmp_path / "src", "small")
    (project / "project.sqlite").unlink()      # a project folder as shipped: toml, design, CPIII
    for run in (1, 2):     # the second run replaces the first's outputs, as the demo does
        doc = demo_session(project, tmp_path / "out", None, None, 40.0, con=Console(file=io.StringIO()))
        assert doc["mode"] == "field session" and doc["fixes_accepted"] >= 3, (run, doc)
        assert (tmp_path / "out" / "survey.xlsx").is_file() and (tmp_path / "out" / "processed" / "track.csv").is_file()
