"""Speed of the TGMS rail-profile fit (Escalona 2021 Sec. 5) in camera frames per second.

A frame is one image pair: Eq. 19 for every laser pixel of both cameras plus the robust profile fit
of both rails. The floor is measured in the same run: one vectorised pass over the same points
(squared distance to a circle), so the ratio says how many such passes a frame costs.

    /work/venv/bin/python benchmarks/bench_tgms_fit.py [--frames 4000] [--repeats 3]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from trolley.tgms.camera import pixels_to_tgms
from trolley.tgms.profiles import rail_profile
from trolley.tgms.simulate import SimulationSettings, simulate
from trolley.tgms.vision import fit_rail


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=4000)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    rate = 200.0
    length = a.frames / rate * 10.0 + 20.0
    rec, _ = simulate(SimulationSettings(length_m=length, speed_m_s=10.0, camera_rate_hz=rate, seed=5))
    cfg = rec.config
    prof = rail_profile(cfg.track.rail_profile, cfg.track.rail_inclination)
    sel = {s: rec.lasers[s].frame < a.frames for s in ("left", "right")}
    n_pts = sum(int(v.sum()) for v in sel.values())
    best = np.inf
    for _ in range(a.repeats):
        t0 = time.perf_counter()
        ok = 0
        for side in ("left", "right"):
            lp = rec.lasers[side]
            m = sel[side]
            p = pixels_to_tgms(cfg.cameras[side], lp.u_px[m], lp.v_px[m])
            fit = fit_rail(prof, lp.frame[m], p[:, 1], p[:, 2], a.frames, side)
            ok += int(fit.ok.sum())
        best = min(best, time.perf_counter() - t0)
    # floor: one vectorised pass over the same number of points
    y = np.random.default_rng(0).normal(size=n_pts)
    z = np.random.default_rng(1).normal(size=n_pts)
    floor = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        _ = (np.hypot(y - 0.1, z - 0.2) - 0.3) ** 2
        floor = min(floor, time.perf_counter() - t0)
    fps = a.frames / best
    print(f"frames {a.frames} (both rails, {n_pts / a.frames:.0f} points per frame), usable {ok / (2 * a.frames):.3f}")
    print(f"profile fit incl. Eq. 19: {best:.3f} s -> {fps:.0f} frames/s (goal >= 500)")
    print(f"floor (one numpy pass over the points): {floor * 1e3:.2f} ms -> fit = {best / floor:.0f} passes")


if __name__ == "__main__":
    main()
