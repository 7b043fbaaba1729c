"""Per-interval processing time of the field session: a 60 m interval at 200 Hz (issue 7).

What the session does when the fix closing an interval is accepted, timed for every interval of a
simulated survey of ``projects/demo`` (1 m/s, fixes every 60 m, RLG IMU at 200 Hz):

1. ``LiveProcessor.add_samples`` (the interval's IMU, odometer and gauge samples) and
   ``add_fix`` (dead reckoning of the interval, the forward filter, the innovation gate);
2. ``smooth_last_interval`` (RTS over the interval, stations, deviations);
3. the interval's track geometry and its defects against the tolerance set
   (``survey.session.interval.interval_check``).

Floor, measured in the same run: ``trolley.deadreckoning.dead_reckon`` alone over the same interval
(the strapdown integration every method has to do). Goal: total < 1 s per interval on 2 cores.

    python benchmarks/bench_interval.py [--intervals 10]
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from survey.commands.simulate import project_settings
from survey.session.interval import interval_check, tolerance_set
from trolley.deadreckoning import dead_reckon
from trolley.landxml import parse_landxml
from trolley.live import LiveProcessor
from trolley.sensors import IMU_PRESETS
from trolley.truthsim import SimulationConfig, simulate_survey

DEMO = Path(__file__).resolve().parents[1] / "projects" / "demo"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--intervals", type=int, default=10)
    args = ap.parse_args()
    kwargs, preset, xml = project_settings(DEMO)
    kwargs["imu"] = IMU_PRESETS[preset]
    cfg = SimulationConfig(**{**kwargs, "length_m": 60.0 * args.intervals})
    design = parse_landxml(xml)
    sim = simulate_survey(design, cfg)
    raw = sim.session
    print(f"simulated {cfg.length_m:g} m, {args.intervals} intervals of {cfg.fix_spacing_m:g} m at "
          f"{cfg.imu_rate_hz:g} Hz ({raw.imu_t_s.size:,} IMU samples)")
    lp = LiveProcessor(raw.meta, design)
    ss = raw.meta.static_s
    s = raw.imu_t_s <= ss
    lp.align(raw.imu_t_s[s], raw.imu_w_rad_s[s], raw.imu_f_m_s2[s])
    fx = raw.fixes
    lp.add_fix(fx.t_s[0], fx.point[0], fx.enh_m[0], fx.sigma_m[0])
    tol = tolerance_set("default")
    tr = raw.meta.trolley
    rows = []
    a = ss
    for k in range(1, len(fx)):
        b = fx.t_s[k]
        si = (raw.imu_t_s > a) & (raw.imu_t_s <= b)
        so = (raw.odo_t_s > a) & (raw.odo_t_s <= b)
        sg = (raw.gauge_t_s > a) & (raw.gauge_t_s <= b)
        t0 = time.perf_counter()
        lp.add_samples(raw.imu_t_s[si], raw.imu_w_rad_s[si], raw.imu_f_m_s2[si], raw.odo_t_s[so],
                       raw.odo_distance_m[so], raw.gauge_t_s[sg], raw.gauge_m[sg])
        v = lp.add_fix(fx.t_s[k], fx.point[k], fx.enh_m[k], fx.sigma_m[k])
        t1 = time.perf_counter()
        r = lp.smooth_last_interval()
        t2 = time.perf_counter()
        chk = interval_check(r.stations, design, tol, tr.rail_spacing_m, tr.nominal_gauge_m)
        t3 = time.perf_counter()
        # floor: the strapdown integration of the same interval on its own
        align = replace(lp.alignment, t_end_s=float(raw.imu_t_s[si][0]))
        f0 = time.perf_counter()
        dead_reckon(raw.imu_t_s[si], raw.imu_w_rad_s[si], raw.odo_t_s[so], raw.odo_distance_m[so], align,
                    raw.meta.latitude_rad, raw.meta.height_m, tr.imu_misalignment_rad)
        f1 = time.perf_counter()
        rows.append((k, int(si.sum()), v.accepted, t1 - t0, t2 - t1, t3 - t2, t3 - t0, f1 - f0, len(chk.defects)))
        a = b
    print(f"{'int':>3} {'IMU':>6} {'acc':>4} {'filter s':>9} {'smooth s':>9} {'geometry s':>10} {'total s':>8} "
          f"{'floor s':>8} {'ratio':>6} {'defects':>7}")
    for k, n, acc, f, sm, g, tot, fl, nd in rows:
        print(f"{k:3d} {n:6d} {str(acc):>4} {f:9.3f} {sm:9.3f} {g:10.3f} {tot:8.3f} {fl:8.3f} {tot / fl:6.1f} {nd:7d}")
    tot = np.array([r[6] for r in rows])
    fl = np.array([r[7] for r in rows])
    print(f"per interval: median {np.median(tot):.3f} s, max {tot.max():.3f} s (goal < 1 s); "
          f"floor (dead reckoning alone) median {np.median(fl):.3f} s; ratio median {np.median(tot / fl):.1f}")


if __name__ == "__main__":
    main()
