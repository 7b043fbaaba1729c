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
