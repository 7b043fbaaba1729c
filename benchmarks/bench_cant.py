"""Cant and twist against the truth, and the honesty of the cant's sigma (docs/engine.md, step 3
and track.csv's ``sigma_cant_mm``).

Simulated surveys with the demo project's settings (1.2 km, fixes every 60 m), for each IMU grade
over a range of seeds: the RMS cant error and the pooled RMS of error / sigma; the mean error of
each survey against the level sigma (the part common to the whole survey: the accelerometers'
level at the stops); the rest, within each survey, against the drift part of the sigma (the
gyros between the levelled stops); and the twist error (3 m base), in which the common part
cancels. Accuracy, not speed: the seconds are printed for scale only.

    python benchmarks/bench_cant.py [--imu mems rlg fog] [--seeds 0-23]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from survey.commands.simulate import project_settings
from trolley.engine import ProcessConfig, level_sigma_rad, process_session
from trolley.landxml import parse_landxml
from trolley.sensors import IMU_PRESETS
from trolley.truthsim import SimulationConfig, simulate_survey

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--imu", nargs="+", default=["mems", "rlg", "fog"], choices=sorted(IMU_PRESETS))
    ap.add_argument("--seeds", default="0-23", help="first-last")
    args = ap.parse_args()
    first, _, last = args.seeds.partition("-")
    seeds = range(int(first), int(last or first) + 1)
    kwargs, _, xml = project_settings(ROOT / "projects" / "demo")
    design = parse_landxml(xml)
    config = ProcessConfig()
    print(f"{'imu':5s} {'cant rms mm':>11s} {'e/s':>5s} {'mean/level':>10s} {'within mm':>9s} "
          f"{'drift sigma mm':>14s} {'twist sd mm':>11s} {'s':>5s}")
    for imu in args.imu:
        errors, ratios, means, within, drift_var, twist = [], [], [], [], [], []
        t0 = time.perf_counter()
        for seed in seeds:
            sim = simulate_survey(design, SimulationConfig(**{**kwargs, "imu": IMU_PRESETS[imu], "seed": seed}))
            r = process_session(sim.session, design, config, with_observability=False)
            st = r.stations
            rail = sim.session.meta.trolley.rail_spacing_m
            true_cant = rail * np.sin(np.interp(st.t_s, sim.truth.t_s, sim.truth.roll_rad))
            e = st.cant_m - true_cant
            level = rail * level_sigma_rad(r.alignment, r.config)
            errors.append(e)
            ratios.append(e / st.sigma_cant_m)
            means.append(e.mean() / level)
            within.append(np.mean((e - e.mean()) ** 2))
            drift_var.append(np.mean(np.maximum(st.sigma_cant_m ** 2 - level ** 2, 0.0)))
            s = np.abs(st.chainage_m)
            true_twist = true_cant - np.interp(s - config.twist_base_m, s, true_cant, left=np.nan)
            twist.append(st.twist_m - true_twist)
        e, q, tw = np.concatenate(errors), np.concatenate(ratios), np.concatenate(twist)
        print(f"{imu:5s} {1e3 * np.sqrt(np.mean(e ** 2)):11.3f} {np.sqrt(np.mean(q ** 2)):5.2f} "
              f"{np.sqrt(np.mean(np.square(means))):10.2f} {1e3 * np.sqrt(np.mean(within)):9.3f} "
              f"{1e3 * np.sqrt(np.mean(drift_var)):14.3f} {1e3 * np.nanstd(tw):11.3f} "
              f"{time.perf_counter() - t0:5.0f}", flush=True)


if __name__ == "__main__":
    main()
