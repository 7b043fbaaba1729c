"""A small simulated project for the field-session tests (not a test module)."""
from __future__ import annotations

import os
import pickle
import re
import shutil
from pathlib import Path
from typing import Callable

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


def fix_covariance_by_hand(fix, setup, instrument) -> np.ndarray:
    """(3, 3) E, N, H covariance a fix must carry, written out by hand for the simulated sessions' flat
    polar model (no curvature, grid scale 1): the polar measurement's part (across the line the
    direction sigma x horizontal distance, along it and in height the zenith and distance sigmas
    shared by sin z, cos z) plus the setup's station and orientation covariance carried to the fix
    (E moves by dN and N by -dE per radian of orientation), all scaled by sigma0^2 when sigma0 > 1."""
    c = setup.covariance
    de, dn, dh = fix.e_m - setup.station_enh_m[0], fix.n_m - setup.station_enh_m[1], fix.h_m - setup.station_enh_m[2]
    hd = np.hypot(de, dn)
    sd = np.hypot(hd, dh)
    sa, ca, sz, cz = de / hd, dn / hd, hd / sd, dh / sd
    s_d = instrument.distance_m + instrument.distance_scale * sd
    across2 = (instrument.direction_rad * hd) ** 2
    along2 = (s_d * sz) ** 2 + (instrument.zenith_rad * sd * cz) ** 2
    up2 = (s_d * cz) ** 2 + (instrument.zenith_rad * sd * sz) ** 2
    along_up = sz * cz * (s_d**2 - (instrument.zenith_rad * sd) ** 2)
    polar = np.array([[across2 * ca**2 + along2 * sa**2, (along2 - across2) * sa * ca, along_up * sa],
                      [(along2 - across2) * sa * ca, across2 * sa**2 + along2 * ca**2, along_up * ca],
                      [along_up * sa, along_up * ca, up2]])
    setup_part = np.array([[c[0, 0] + 2 * dn * c[0, 3] + dn**2 * c[3, 3],
                            c[0, 1] - de * c[0, 3] + dn * c[1, 3] - de * dn * c[3, 3], c[0, 2] + dn * c[2, 3]],
                           [0.0, c[1, 1] - 2 * de * c[1, 3] + de**2 * c[3, 3], c[1, 2] - de * c[2, 3]],
                           [0.0, 0.0, c[2, 2]]])
    setup_part = np.triu(setup_part) + np.triu(setup_part, 1).T
    return max(1.0, setup.sigma0**2) * (polar + setup_part)


def fix_sigmas_by_hand(fix, setup, instrument) -> np.ndarray:
    """(3,) the E, N, H sigma a fix must carry: the diagonal of :func:`fix_covariance_by_hand`."""
    return np.sqrt(np.diag(fix_covariance_by_hand(fix, setup, instrument)))


def shared_copy(tmp_path_factory, name: str, build: Callable[[Path], object]) -> tuple[Path, object]:
    """A folder built once per test run, whatever the number of xdist workers, and this worker's
    own copy of it: ``(copy, what build returned)``.

    A module fixture is built once per worker that runs a test of the module: with 4 workers the
    reference session of tests/test_session_run.py (10-20 s) was run up to 4 times. ``build(folder)``
    runs under a lock in a folder all workers share (the run's base temporary folder); each worker
    then works on its own copy, so no two write into one project store.
    """
    import fcntl

    base = tmp_path_factory.getbasetemp()
    shared = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / f"shared-{name}"
    with open(f"{shared}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)    # released when the file closes
        if not (shared / ".built").is_file():
            shutil.rmtree(shared, ignore_errors=True)   # a build that failed half way
            shared.mkdir(parents=True)
            (shared / ".result.pickle").write_bytes(pickle.dumps(build(shared)))
            (shared / ".built").touch()
        result = pickle.loads((shared / ".result.pickle").read_bytes())
        copy = tmp_path_factory.mktemp(name)
        shutil.copytree(shared, copy, dirs_exist_ok=True, symlinks=True)
    return copy, result
