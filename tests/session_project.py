"""A small simulated project for the field-session tests (not a test module)."""
from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np

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


def fix_sigmas_by_hand(fix, setup, fix_sigma_m: float) -> np.ndarray:
    """(3,) the E, N, H sigma a fix must carry, written out by hand: the measurement's sigma plus the
    setup's station and orientation covariance (scaled by sigma0^2 when sigma0 > 1) carried to the
    fix, where E moves by dN and N by -dE per radian of orientation."""
    c = setup.covariance * max(1.0, setup.sigma0**2)
    de, dn = fix.e_m - setup.station_enh_m[0], fix.n_m - setup.station_enh_m[1]
    sig2 = fix_sigma_m**2
    return np.sqrt([sig2 + c[0, 0] + 2 * dn * c[0, 3] + dn**2 * c[3, 3],
                    sig2 + c[1, 1] - 2 * de * c[1, 3] + de**2 * c[3, 3],
                    sig2 + c[2, 2]])
