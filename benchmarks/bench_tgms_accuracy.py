"""Accuracy of the TGMS pipeline on synthetic recordings, and its speed for 1 km of track.

For each seed x speed, a recording is simulated (trolley.tgms.simulate) and processed with every
variant; the errors against the truth after the 3-25 m band-pass (std, mm) are printed as
reported (odometry stations) and registered (frames at their true stations), with the coverage
of the filters' 95 % intervals (unfiltered, mean error removed). The floor for the speed figure
is the time to simulate the same kilometre (same run).

    python benchmarks/bench_tgms_accuracy.py [--seeds 1 2 3] [--speeds 5 15]
        [--length-m 300] [--km] [--cml] [--cml-ekf] [--cml-box absolute] [--laser-x-m 0.3]
        [--constant-encoder]

The simulated encoder has, besides its constant 0.1 % diameter error, the errors the odometry
does not model (simulate.ENCODER_DRIFT: creep 1e-4 s^2/m times the longitudinal acceleration and a
1e-4 rms rolling-radius variation with a 100 m correlation length); --constant-encoder switches
them off (the odometry's own single-scale model, for comparison).

Variants: kf+ltv (default: odometry by the heading fit and the Eq. 41 anchors fused into one encoder
scale, ``odometry_method="fused"``), kf+ltv with the published odometry (Eq. 41 anchors at the curve
exits and the linear re-mapping of Fig. 11, ``odometry_method="anchors"``), madgwick+ltv, kf+ltv
with the fused anchors at every curve entry and exit (``odometry_windows="entry_exit"``), kf+ekf;
with --cml the attitude filter tuned by CML per recording (60 evaluations), with --cml-ekf the
12-state smoother tuned by CML (150 evaluations). The last column is the odometry's encoder scale
error k and its 1-sigma (the simulated wheel is 0.1 % large: k = +1e-3).
Where the reported error comes from: "registered" removes the odometry's station error, so
reported - registered (in quadrature) is the positioning part.
"""
from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from trolley.tgms.accuracy import accuracy
from trolley.tgms.params import TgmsParams
from trolley.tgms.pipeline import process
from trolley.tgms.simulate import CONSTANT_ENCODER, SimulationSettings, simulate

NAMES = ("gauge_variation", "cross_level", "alignment", "vertical_profile")
SHORT = {"gauge_variation": "gv", "cross_level": "cl", "alignment": "al", "vertical_profile": "vp"}


def variants():
    out = {"kf+ltv": TgmsParams(), "kf+ltv Eq.41 anch": TgmsParams(odometry_method="anchors"),
           "madgwick+ltv": TgmsParams(orientation="madgwick"),
           "kf+ltv entry/exit": TgmsParams(odometry_windows="entry_exit")}
    try:
        import trolley.tgms.ekf  # noqa: F401
        out["kf+ekf"] = TgmsParams(trajectory="ekf")
    except ImportError:
        pass
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--speeds", type=float, nargs="+", default=[5.0, 15.0])
    ap.add_argument("--length-m", type=float, default=300.0)
    ap.add_argument("--km", action="store_true", help="also time the whole pipeline on 1 km")
    ap.add_argument("--cml", action="store_true", help="add kf+ltv with the attitude filter tuned by CML per recording")
    ap.add_argument("--cml-ekf", action="store_true", help="add kf+ekf with the 12-state smoother tuned by CML per recording")
    ap.add_argument("--cml-box", default="relative", help="CML search box: relative or absolute (Eq. 17)")
    ap.add_argument("--laser-x-m", type=float, default=0.0, help="laser planes this far ahead of the IMU")
    ap.add_argument("--constant-encoder", action="store_true",
                    help="encoder creep and rolling-radius variation off (simulate.CONSTANT_ENCODER)")
    a = ap.parse_args()
    drift = CONSTANT_ENCODER if a.constant_encoder else {}
    if drift:
        print("constant-scale encoder: " + ", ".join(f"{k}={v:g}" for k, v in drift.items()))
    vs = variants()
    if a.cml:
        vs["kf(CML)+ltv"] = "cml"
    if a.cml_ekf:
        vs["kf+ekf(CML)"] = "cml-ekf"
    rows = {k: [] for k in vs}
    print(f"{'variant':17s} {'seed':>4s} {'V':>5s} | std as reported (mm): gv cl al vp | registered: gv cl al vp "
          "| 95% coverage gv cl al vp | odometry")
    for speed in a.speeds:
        for seed in a.seeds:
            rec, tr = simulate(SimulationSettings(length_m=a.length_m, speed_m_s=speed, seed=seed,
                                                  laser_plane_x_m=a.laser_x_m, **drift))
            truth = {k: getattr(tr, k) for k in dataclasses.asdict(tr)}
            for name, p in vs.items():
                if p in ("cml", "cml-ekf"):
                    from trolley.tgms.tuning import tune_cml
                    if p == "cml":
                        p, _ = tune_cml(rec, max_evaluations=60, seed=0, box=a.cml_box)
                    else:
                        p, _ = tune_cml(rec, max_evaluations=150, seed=0, model="ekf", box=a.cml_box)
                res = process(rec, p)
                acc = accuracy(res.frames, truth, res.vision.t_s, laser_offset_m=res.laser_offset_m)
                rows[name].append(acc)
                f = lambda d: " ".join(f"{d[n]:.3f}" for n in NAMES)
                print(f"{name:17s} {seed:4d} {speed:5.1f} | {f(acc.std_mm)} | {f(acc.std_registered_mm)} | "
                      + " ".join(f"{acc.coverage95[n]:.2f}" for n in NAMES)
                      + (f" | odometry k {res.odometry.scale_error * 1e3:+.2f}e-3 +- "
                         f"{res.odometry.sigma_scale_error * 1e3:.2f}e-3" if np.isfinite(res.odometry.scale_error)
                         else " | odometry: Eq. 41 anchors"))
    print("\nworst case over seeds and speeds (std, mm; limits gv 0.15, cl 0.15, al 0.7, vp 0.35):")
    for name, accs in rows.items():
        w = {n: max(x.std_mm[n] for x in accs) for n in NAMES}
        wr = {n: max(x.std_registered_mm[n] for x in accs) for n in NAMES}
        cov = {n: np.mean([x.coverage95[n] for x in accs]) for n in NAMES}
        sm = {n: np.median([x.sigma_median_mm[n] for x in accs]) for n in NAMES}
        eu = {n: np.median([x.error_std_unfiltered_mm[n] for x in accs]) for n in NAMES}
        print(f"  {name:17s} reported " + " ".join(f"{SHORT[n]} {w[n]:.3f}" for n in NAMES)
              + " | registered " + " ".join(f"{SHORT[n]} {wr[n]:.3f}" for n in NAMES)
              + " | mean coverage " + " ".join(f"{SHORT[n]} {cov[n]:.2f}" for n in NAMES)
              + " | median sigma / unfiltered error std " + " ".join(f"{SHORT[n]} {sm[n]:.3f}/{eu[n]:.3f}" for n in NAMES))
    if a.km:
        t0 = time.perf_counter()
        rec, tr = simulate(SimulationSettings(length_m=1000.0, speed_m_s=10.0, seed=7, **drift))
        t_sim = time.perf_counter() - t0
        for name, p in vs.items():
            if p in ("cml", "cml-ekf"):
                continue
            t0 = time.perf_counter()
            res = process(rec, p)
            t_proc = time.perf_counter() - t0
            print(f"1 km at 10 m/s ({len(res.vision.frame)} frames, {len(rec.imu_t_s)} IMU samples): "
                  f"{name} {t_proc:.1f} s ({t_proc / t_sim:.2f} x the simulation's {t_sim:.1f} s); stages "
                  + ", ".join(f"{k} {v:.1f}" for k, v in res.timings_s.items()))


if __name__ == "__main__":
    main()
