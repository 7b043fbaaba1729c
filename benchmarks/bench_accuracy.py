"""Accuracy of the stop-and-go engine against the full 3-D truth simulator (issue 2).

Simulated survey of the demo design: 1.2 km, fixes every 60 m, total station 0.6 mm, 900 s static
alignment, 200 Hz IMU. For each IMU grade and smoother it prints the RMS of the lateral,
longitudinal and vertical error of the smoothed track reference point against the truth, and the
RMS of error/sigma (1 = honest sigmas), over several seeds.

    python benchmarks/bench_accuracy.py [--seeds 3] [--length-m 1200]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from trolley.engine import ProcessConfig, process_session
from trolley.landxml import parse_landxml
from trolley.sensors import IMU_PRESETS
from trolley.truthsim import SimulationConfig, simulate_survey
from trolley.validation import track_errors

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--length-m", type=float, default=1200.0)
    ap.add_argument("--static-s", type=float, default=900.0)
    ap.add_argument("--grades", default="rlg,fog,mems")
    args = ap.parse_args()
    design = parse_landxml((ROOT / "projects" / "demo" / "alignment.xml").read_text(encoding="utf-8"))
    print(f"{'grade':5} {'smoother':8} {'seed':>4} {'lat mm':>7} {'lon mm':>7} {'vert mm':>7} "
          f"{'lat e/s':>7} {'vert e/s':>8} {'rejected':>8} {'sec':>5}")
    for grade in args.grades.split(","):
        for smoother in ("rts", "tfs", "none"):
            rows = []
            for seed in range(args.seeds):
                sim = simulate_survey(design, SimulationConfig(length_m=args.length_m, static_s=args.static_s,
                                                               imu=IMU_PRESETS[grade], seed=seed))
                t0 = time.perf_counter()
                res = process_session(sim.session, design, ProcessConfig(smoother=smoother),
                                      with_observability=False)
                dt = time.perf_counter() - t0
                tj = res.trajectory
                e = track_errors(tj.t_s, tj.distance_m, tj.enh_m, tj.sigma_enh_m, sim.truth)
                rms = np.array(e.rms_m()) * 1e3
                nr = e.normalised_rms()
                rows.append([*rms, nr[0], nr[2]])
                print(f"{grade:5} {smoother:8} {seed:4d} {rms[0]:7.3f} {rms[1]:7.3f} {rms[2]:7.3f} "
                      f"{nr[0]:7.2f} {nr[2]:8.2f} {res.summary['fixes_rejected']:8d} {dt:5.1f}")
            r = np.array(rows)
            # pooled over seeds: RMS of RMS (equal sample counts per seed)
            pooled = np.sqrt(np.mean(r**2, axis=0))
            print(f"{grade:5} {smoother:8} {'all':>4} {pooled[0]:7.3f} {pooled[1]:7.3f} {pooled[2]:7.3f} "
                  f"{pooled[3]:7.2f} {pooled[4]:8.2f}")


if __name__ == "__main__":
    main()
