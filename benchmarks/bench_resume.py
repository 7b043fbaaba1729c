"""Crash safety of the field session: SIGKILL at many points, ``trolley survey resume``, compared
with an uninterrupted run of the same scripted simulated survey (issue 12).

The small project of ``tests/session_project.py`` (two 60 m intervals at 2 m/s) is surveyed with
the crew script below (a fix at each stop, a note and a station change with its overlap check at
the second stop). One reference run goes through without interruption. Each other run is killed
with SIGKILL at one point, then resumed; the points are odometer distances (in the static
alignment, in an interval, at a stop) and delays after the ``station_change`` event (in the
station change: while the CPIII points are measured, after the new setup is stored, around the
overlap measurement). For each, the study reports whether the resumed session has the same
accepted fixes (labels and setups) and the same overlap checks (verdict and value) as the
reference, and the largest difference of the final tracks' positions.

    python benchmarks/bench_resume.py [--points 12] [--speedup 25] [--keep DIR]

Not a timed benchmark: the figures are agreements (mm and counts), which do not depend on the
machine; a loaded machine only moves where in the session each kill lands.
"""
from __future__ import annotations

import argparse
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from session_project import make_project  # noqa: E402

TROLLEY = [sys.executable, "-m", "survey.cli"]
SCRIPT = "fix\nmove\nfix\nnote hello from the crew\nstation\nmove\nfix\nend\n"
#: (what to wait for, value): odometer distance in m, or seconds after the station_change event
KILL_POINTS = [("odometer", 0.0), ("station", 0.0), ("odometer", 30.0), ("station", 0.15),
               ("odometer", 59.9), ("station", 0.3), ("odometer", 90.0), ("station", 0.5),
               ("station", 0.05), ("station", 0.8), ("station", 0.25), ("station", 1.2),
               ("station", 0.4), ("station", 0.1), ("station", 0.6), ("station", 2.0)]


def _query(db: Path, sql: str, name: str):
    try:
        c = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1.0)
        try:
            sid = c.execute("SELECT id FROM session WHERE name = ?", (name,)).fetchone()
            return c.execute(sql, sid).fetchone()[0] if sid else None
        finally:
            c.close()
    except sqlite3.Error:
        return None


def _odometer_m(db: Path, name: str) -> float:
    v = _query(db, "SELECT MAX(distance_m) FROM odometer_sample WHERE session_id = ?", name)
    return float(v) if v is not None else -1.0


def _station_change_seen(db: Path, name: str) -> bool:
    return bool(_query(db, "SELECT COUNT(*) FROM session_event WHERE session_id = ? AND kind = 'station_change'", name))


def kill_at(root: Path, name: str, what: str, value: float, speedup: str) -> str:
    """Start session ``name`` and SIGKILL it at the kill point; returns where it landed."""
    db = root / "projects" / "t1" / "project.sqlite"
    p = subprocess.Popen(TROLLEY + ["survey", "start", "t1", "--root", "projects", "--session", name,
                                    "--simulate", "--speedup", speedup, "--script", "crew.txt"],
                         cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline and p.poll() is None:
        if what == "odometer" and _odometer_m(db, name) >= value:
            break
        if what == "station" and _station_change_seen(db, name):
            time.sleep(value)
            break
        time.sleep(0.02)
    if p.poll() is not None:
        raise SystemExit(f"{name}: the session ended before the kill point {what} {value}")
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    return describe(root, name)


def describe(root: Path, name: str) -> str:
    """What the store holds of a session: setups, fixes, odometer distance."""
    from survey.store import ProjectStore

    with ProjectStore.open(root / "projects" / "t1") as st:
        sid = st.session(name).session_id
        return (f"{len(st.station_setups(sid))} setups, {len(st.fixes(sid))} fixes, "
                f"odometer {_odometer_m(root / 'projects' / 't1' / 'project.sqlite', name):.1f} m")


def outcome(st, name: str):
    """(accepted fixes, overlap checks, final track) of a session."""
    sid = st.session(name).session_id
    setups = {s.setup_id: i for i, s in enumerate(st.station_setups(sid))}
    fixes = st.fixes(sid)
    accepted = [(f.point, setups.get(f.setup_id)) for f in fixes if f.accepted]
    overlaps = [(f.point, f.accepted, f.reason, np.array([f.e_m, f.n_m, f.h_m])) for f in fixes
                if f.reason.startswith("overlap check")]
    runs = [r for r in st.processing_runs(sid) if r.kind == "final"]
    return accepted, overlaps, st.track(runs[-1].run_id) if runs else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--points", type=int, default=12)
    ap.add_argument("--speedup", default="25")
    ap.add_argument("--keep", type=Path, default=None, help="work in this folder and keep it")
    args = ap.parse_args()
    from survey.store import ProjectStore

    root = args.keep or Path(tempfile.mkdtemp(prefix="bench_resume_"))
    root.mkdir(parents=True, exist_ok=True)
    make_project(root / "projects")
    (root / "crew.txt").write_text(SCRIPT)
    env = {**os.environ, "COLUMNS": "160"}
    r = subprocess.run(TROLLEY + ["survey", "start", "t1", "--root", "projects", "--session", "ref", "--simulate",
                                  "--speedup", args.speedup, "--script", "crew.txt"], cwd=root, env=env,
                       capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(r.stderr[-3000:])
    rows = []
    # the floor: a second uninterrupted run of the same survey (host timing only)
    points = [("none", 0.0)] + KILL_POINTS[: args.points]
    for i, (what, value) in enumerate(points):
        name = f"k{i:02d}"
        if what == "none":
            landed = "uninterrupted"
            r = subprocess.run(TROLLEY + ["survey", "start", "t1", "--root", "projects", "--session", name,
                                          "--simulate", "--speedup", args.speedup, "--script", "crew.txt"],
                               cwd=root, env=env, capture_output=True, text=True)
        else:
            landed = kill_at(root, name, what, value, args.speedup)
            r = subprocess.run(TROLLEY + ["survey", "resume", "t1", "--root", "projects", "--session", name],
                               cwd=root, env=env, capture_output=True, text=True)
        if r.returncode:
            rows.append((name, what, value, landed, False, False, float("nan"), r.stderr.strip()[-300:]))
            continue
        with ProjectStore.open(root / "projects" / "t1") as st:
            fa, oa, ta = outcome(st, "ref")
            fb, ob, tb = outcome(st, name)
        same_fixes = fa == fb
        same_overlap = len(oa) == len(ob) and all(
            a[:3] == b[:3] and np.max(np.abs(a[3] - b[3])) < 1e-9 for a, b in zip(oa, ob))
        if tb is not None and np.array_equal(ta.chainage_m, tb.chainage_m):
            d = 1e3 * float(np.max(np.abs(ta.enh_m - tb.enh_m)))
        else:
            d = float("nan")
        rows.append((name, what, value, landed, same_fixes, same_overlap, d, ""))
    print(f"{'run':4} {'kill point':22} {'what the store held':42} {'fixes':6} {'overlap':8} max |d| mm")
    for name, what, value, landed, sf, so, d, err in rows:
        point = {"odometer": f"odometer {value:g} m", "station": f"station change +{value:g} s"}.get(what, "-")
        print(f"{name:4} {point:22} {landed:42} {'same' if sf else 'DIFF':6} {'same' if so else 'DIFF':8} "
              f"{d:.4f} {err}")
    print(f"\nfloor (a second uninterrupted run): max |d| {rows[0][6]:.4f} mm")
    rows = rows[1:]
    ds = np.array([r[6] for r in rows])
    print(f"{len(rows)} kill points: accepted fixes the same in {sum(r[4] for r in rows)}, overlap checks the "
          f"same in {sum(r[5] for r in rows)}; max track difference {np.nanmax(ds) if np.isfinite(ds).any() else float('nan'):.4f} mm"
          f" (no final track, or on other stations: {int(np.sum(~np.isfinite(ds)))})")
    if args.keep is None:
        import shutil

        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
