"""One bad cell at the end of a large imu.csv: reported in about the time a valid file takes (issue 12).

Writes a valid ``imu.csv`` of ``--rows`` rows (default 5 million, about 550 MB) and copies of it
with one bad cell in the last row: a text cell (``x``), a non-finite one (``inf``) and a finite
but absurd one (``1e308``). Each file is read by :func:`survey.sessionio._read_numeric` in a
fresh process (so that its peak memory is its own) and the wall time and the peak resident
memory (``resource.getrusage(RUSAGE_SELF).ru_maxrss``) are printed, with the ratio of each bad
file's time to the valid file's. The floor is the valid file: a ratio near 1 means the error
costs no more than the read itself.

    python benchmarks/bench_bad_cell.py [--rows 5000000] [--keep DIR]
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

_CHILD = """
import json, resource, sys, time
from pathlib import Path
sys.path.insert(0, {repo!r})
from survey.sessionio import IMU_COLUMNS, SessionFormatError, _read_numeric
import pandas  # noqa: F401  (imported before the clock starts)
t0 = time.perf_counter()
try:
    _read_numeric(Path({path!r}), IMU_COLUMNS)
    msg = None
except SessionFormatError as exc:
    msg = str(exc)
wall = time.perf_counter() - t0
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({{"wall_s": wall, "peak_mb": rss, "message": msg}}))
"""


def write_imu(path: Path, rows: int, seed: int = 1) -> None:
    """A valid imu.csv at 200 Hz (values of a resting IMU with noise), written in blocks."""
    rng = np.random.default_rng(seed)
    block = 500_000
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("t_s,wx_rad_s,wy_rad_s,wz_rad_s,fx_m_s2,fy_m_s2,fz_m_s2\n")
        for start in range(0, rows, block):
            n = min(block, rows - start)
            t = (np.arange(start, start + n) + 1) * 0.005
            w = rng.normal(0.0, 1e-4, (n, 3))
            f = rng.normal(0.0, 1e-2, (n, 3)) + np.array([0.0, 0.0, -9.79])
            np.savetxt(fh, np.column_stack([t, w, f]), fmt=["%.3f"] + ["%.10g"] * 6, delimiter=",")


def with_bad_last_cell(src: Path, dst: Path, value: str) -> None:
    """Copy ``src`` with the wy_rad_s cell of the last row replaced by ``value``."""
    shutil.copyfile(src, dst)
    with open(dst, "rb+") as fh:
        fh.seek(0, 2)
        size = fh.tell()
        fh.seek(max(0, size - 400))
        tail = fh.read()
        start = tail.rstrip(b"\n").rfind(b"\n") + 1
        cells = tail[start:].rstrip(b"\n").split(b",")
        cells[2] = value.encode()
        fh.seek(size - len(tail) + start)
        fh.truncate()
        fh.write(b",".join(cells) + b"\n")


def measure(path: Path) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD.format(repo=str(REPO), path=str(path))],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=5_000_000)
    ap.add_argument("--keep", type=Path, default=None, help="folder to keep the files in (default: a temp folder)")
    a = ap.parse_args()
    folder = a.keep or Path(tempfile.mkdtemp(prefix="bench_bad_cell-"))
    folder.mkdir(parents=True, exist_ok=True)
    try:
        valid = folder / "imu.csv"
        if not valid.exists():
            write_imu(valid, a.rows)
        cases = {"valid": valid}
        for name, value in (("text x", "x"), ("inf", "inf"), ("1e308", "1e308")):
            p = folder / f"imu_{name.split()[0]}.csv"
            if not p.exists():
                with_bad_last_cell(valid, p, value)
            cases[name] = p
        print(f"{a.rows} rows, {valid.stat().st_size / 1e6:.0f} MB")
        base = None
        for name, p in cases.items():
            r = measure(p)
            base = base or r["wall_s"]
            print(f"{name:8s} {r['wall_s']:6.2f} s  ratio {r['wall_s'] / base:5.2f}  peak {r['peak_mb']:7.0f} MB  "
                  f"{r['message']}")
    finally:
        if a.keep is None:
            shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
