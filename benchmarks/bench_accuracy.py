"""Accuracy of the stop-and-go engine against the full 3-D truth simulator (issue 2).

Simulated survey of the demo design: 1.2 km, fixes every 60 m, total station 0.6 mm, 900 s static
alignment, 200 Hz IMU. For each IMU grade and smoother it prints the RMS of the lateral,
longitudinal and vertical error of the smoothed track reference point against the truth, the
RMS of error/sigma (1 = honest sigmas) and the share of samples outside 3 sigma, per seed and
pooled over the seeds (the same simulated sessions for every smoother).

Then PASS/FAIL against the issue's criteria, for the navigation-grade RLG with either smoother:
pooled RMS of the lateral and of the vertical error <= 0.6 mm, pooled RMS of error/sigma of both
in 0.7 .. 1.3. FOG, MEMS and the filtered-only track ("none") are printed for contrast.

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
SMOOTHERS = ("rts", "tfs", "none")
#: The issue's criteria (RLG, smoothed): RMS lateral and vertical error, and RMS of error/sigma.
MAX_RMS_M = 0.6e-3
RATIO_RANGE = (0.7, 1.3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--length-m", type=float, default=1200.0)
    ap.add_argument("--static-s", type=float, default=900.0)
    ap.add_argument("--grades", default="rlg,fog,mems")
    args = ap.parse_args()
    design = parse_landxml((ROOT / "projects" / "demo" / "alignment.xml").read_text(encoding="utf-8"))
    head = (f"{'grade':5} {'smoother':8} {'seed':>4} {'lat mm':>7} {'lon mm':>7} {'vert mm':>7} "
            f"{'lat e/s':>7} {'vert e/s':>8} {'>3s %':>6} {'rejected':>8} {'sec':>5}")
    print(head)
    pooled = {}
    for grade in args.grades.split(","):
        errs = {sm: [] for sm in SMOOTHERS}
        for seed in range(args.seeds):
            sim = simulate_survey(design, SimulationConfig(length_m=args.length_m, static_s=args.static_s,
                                                           imu=IMU_PRESETS[grade], seed=seed))
            for smoother in SMOOTHERS:
                t0 = time.perf_counter()
                res = process_session(sim.session, design, ProcessConfig(smoother=smoother),
                                      with_observability=False)
                dt = time.perf_counter() - t0
                tj = res.trajectory
                e = track_errors(tj.t_s, tj.distance_m, tj.enh_m, tj.sigma_enh_m, sim.truth, cov_EN_m2=tj.cov_EN_m2)
                errs[smoother].append(e)
                rms = np.array(e.rms_m()) * 1e3
                nr = e.normalised_rms()
                out3 = 100 * np.mean(np.abs(np.concatenate([e.lateral_m / e.sigma_lateral_m,
                                                            e.vertical_m / e.sigma_vertical_m])) > 3)
                print(f"{grade:5} {smoother:8} {seed:4d} {rms[0]:7.3f} {rms[1]:7.3f} {rms[2]:7.3f} "
                      f"{nr[0]:7.2f} {nr[2]:8.2f} {out3:6.2f} {res.summary['fixes_rejected']:8d} {dt:5.1f}")
        for smoother in SMOOTHERS:
            cat = {k: np.concatenate([getattr(e, k) for e in errs[smoother]])
                   for k in ("lateral_m", "longitudinal_m", "vertical_m", "sigma_lateral_m", "sigma_vertical_m")}
            rms = [float(np.sqrt(np.mean(cat[k] ** 2))) for k in ("lateral_m", "longitudinal_m", "vertical_m")]
            q_lat = cat["lateral_m"] / cat["sigma_lateral_m"]
            q_v = cat["vertical_m"] / cat["sigma_vertical_m"]
            ratios = (float(np.sqrt(np.mean(q_lat**2))), float(np.sqrt(np.mean(q_v**2))))
            out3 = 100 * np.mean(np.abs(np.concatenate([q_lat, q_v])) > 3)
            pooled[grade, smoother] = (rms, ratios)
            print(f"{grade:5} {smoother:8} {'all':>4} {rms[0] * 1e3:7.3f} {rms[1] * 1e3:7.3f} {rms[2] * 1e3:7.3f} "
                  f"{ratios[0]:7.2f} {ratios[1]:8.2f} {out3:6.2f}")
    print()
    print(f"criteria (issue 2), pooled over {args.seeds} seeds of {args.length_m / 1000:.1f} km: RMS lateral and "
          f"vertical <= {MAX_RMS_M * 1e3:.1f} mm, RMS e/s in {RATIO_RANGE[0]} .. {RATIO_RANGE[1]}")
    for smoother in ("rts", "tfs"):
        if ("rlg", smoother) not in pooled:
            continue
        rms, ratios = pooled["rlg", smoother]
        for what, value, ok in (
                ("RMS lateral", f"{rms[0] * 1e3:.3f} mm", rms[0] <= MAX_RMS_M),
                ("RMS vertical", f"{rms[2] * 1e3:.3f} mm", rms[2] <= MAX_RMS_M),
                ("RMS e/s lateral", f"{ratios[0]:.2f}", RATIO_RANGE[0] <= ratios[0] <= RATIO_RANGE[1]),
                ("RMS e/s vertical", f"{ratios[1]:.2f}", RATIO_RANGE[0] <= ratios[1] <= RATIO_RANGE[1])):
            print(f"{'PASS' if ok else 'FAIL'}  rlg {smoother:4} {what:17} {value}")


if __name__ == "__main__":
    main()
