"""A small simulated project for the field-session tests (not a test module)."""
from __future__ import annotations

import re
import shutil
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "projects" / "demo"

#: a short survey: 20 s static, two 60 m intervals at 2 m/s, 8 s stops (~104 s of simulated time)
SMALL_SIMULATION = {"length_m": "120.0", "static_s": "20.0", "stop_s": "8.0", "speed_m_s": "2.0"}


def make_project(root: Path, name: str = "t1", tolerance_set: str = "default", **simulation: str) -> Path:
    """A project folder under ``root`` with the demo design and CPIII and a short simulated survey."""
    from survey.commands.project import new

    folder = root / name
    folder.mkdir(parents=True)
    toml = (DEMO / "project.toml").read_text(encoding="utf-8")
    for key, value in {**SMALL_SIMULATION, **simulation}.items():
        toml = re.sub(rf"(?m)^{key}\s*=\s*[^#\n]*", f"{key} = {value} ", toml)
    (folder / "project.toml").write_text(toml, encoding="utf-8")
    for f in ("alignment.xml", "cpiii.csv"):
        shutil.copy(DEMO / f, folder / f)
    new(name, root=root, imu=None, latitude_deg=None, height=None, tolerance_set=tolerance_set, use_toml=True)
    return folder
