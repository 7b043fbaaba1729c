"""Two surveys of one track (``trolley compare``): are the differences within their sigmas?

For each IMU grade, pairs of simulated surveys of one track (the demo project's settings, 1.2 km,
one ``track_seed`` per pair, the sensor errors, fixes and station setups of each survey its own)
are processed by the engine and compared. Printed per IMU: the pooled RMS of difference/sigma
(1 for honest sigmas) lateral / vertical / cant, its range over the pairs, the pairs with a
station beyond 3 sigma, the RMS differences in mm and the D1 / D2 / D3 repeatability of the
relative geometry. Speed: the comparison's time against the time to read the two track.csv
files it compares (the floor, measured in the same run).

    python benchmarks/bench_compare.py [--imu rlg fog mems] [--pairs 8]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from survey.commands.simulate import project_settings
from survey.track_reader import read_track_file
from survey.trackio import write_track_csv
from trolley.engine import ProcessConfig, process_session
from trolley.landxml import parse_landxml
from trolley.repeatability import compare_tracks
from trolley.sensors import IMU_PRESETS
from trolley.truthsim import SimulationConfig, simulate_survey

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--imu", nargs="+", default=["rlg", "fog", "mems"], choices=sorted(IMU_PRESETS))
    ap.add_argument("--pairs", type=int, default=8)
    args = ap.parse_args()
    kwargs, _, xml = project_settings(ROOT / "projects" / "demo")
    design = parse_landxml(xml)
    print(f"{'imu':5s} {'pairs':>5s}  RMS diff/sigma lat / vert / cant (range lat, vert)      beyond --limit  "
          f"RMS diff mm lat / vert    D1 / D2 / D3 lat mm       D1 / D2 / D3 vert mm")
    speed = []
    with tempfile.TemporaryDirectory() as tmp:
        for imu in args.imu:
            z = {q: [] for q in ("lateral", "vertical", "cant")}
            per = {q: [] for q in ("lateral", "vertical")}
            rms = {q: [] for q in ("lateral", "vertical")}
            bands = {q: [] for q in ("lateral", "vertical")}
            beyond = 0
            worst = []
            for pair in range(args.pairs):
                base = replace(SimulationConfig(**kwargs), imu=IMU_PRESETS[imu], track_seed=1000 + pair)
                files = []
                for k in (0, 1):
                    r = process_session(simulate_survey(design, replace(base, seed=2 * pair + k)).session, design,
                                        ProcessConfig(), with_observability=False)
                    files.append(Path(tmp) / f"{imu}{pair}{k}.csv")
                    write_track_csv(files[-1], r)
                t0 = time.perf_counter()
                a, b = (read_track_file(f).track for f in files)
                t1 = time.perf_counter()
                c = compare_tracks(a, b)
                t2 = time.perf_counter()
                speed.append((t1 - t0, t2 - t1))
                for q in z:
                    zq = c.difference.z(q)
                    z[q].append(zq[np.isfinite(zq)])
                for q in per:
                    per[q].append(c.rms_z[q])
                    rms[q].append(c.rms_m[q])
                    bands[q].append([c.band_rms_m[q][n] for n in ("D1", "D2", "D3")])
                beyond += not c.agree
                worst.append(max(float(np.nanmax(np.abs(c.difference.z(q)))) for q in ("lateral", "vertical", "cant")))
            pooled = {q: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for q, v in z.items()}
            mm = {q: 1e3 * float(np.sqrt(np.mean(np.square(v)))) for q, v in rms.items()}
            bd = {q: 1e3 * np.sqrt(np.nanmean(np.square(v), axis=0)) for q, v in bands.items()}
            print(f"{imu:5s} {args.pairs:5d}  {pooled['lateral']:.2f} / {pooled['vertical']:.2f} / {pooled['cant']:.2f} "
                  f"({min(per['lateral']):.2f}-{max(per['lateral']):.2f}, {min(per['vertical']):.2f}-"
                  f"{max(per['vertical']):.2f})          {beyond:2d} of {args.pairs:2d}        "
                  f"{mm['lateral']:.3f} / {mm['vertical']:.3f}           "
                  + " / ".join(f"{x:.4f}" for x in bd["lateral"]) + "   "
                  + " / ".join(f"{x:.4f}" for x in bd["vertical"]))
            worst_text = ", ".join(f"{w:.2f}" for w in sorted(worst))
            print(f"      largest |diff|/sigma of each pair (lateral, vertical, cant): {worst_text}; "
                  + ", ".join(f"{sum(w > k for w in worst)} beyond {k:g}" for k in (3.0, 3.5, 4.0, 4.5)))
    read, comp = np.median(np.array(speed), axis=0)
    print(f"speed: compare {1e3 * comp:.1f} ms median for 1.2 km (1921 stations), {comp / read:.2f} x the time to "
          f"read the two track.csv files ({1e3 * read:.1f} ms)")


if __name__ == "__main__":
    main()
