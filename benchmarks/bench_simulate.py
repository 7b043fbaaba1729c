"""Speed of the truth simulator and of the session writer/reader on a 10 km survey.

Prints seconds to simulate, to write the raw session folder (+ truth.csv) and to read it back,
for a 10 km design (straights, clothoids, 2000-4000 m curves, grades, cant) at 200 Hz, with a
floor measured in the same run (the time numpy needs to draw and cumulate the same number of
normal samples) so the ratios can be compared across machines.

Run:  /work/venv/bin/python benchmarks/bench_simulate.py [--length-m 10000] [--rate-hz 200]
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from survey.sessionio import read_session, write_session, write_truth_csv
from trolley.alignment import (Alignment, Arc, CantProfile, Clothoid, HorizontalAlignment, Line,
                               VerticalProfile)
from trolley.truthsim import SimulationConfig, simulate_survey


def long_alignment(length_m: float) -> Alignment:
    """Repeating straight / transition / curve pattern (alternating hands) over ``length_m``."""
    elements, cant_s, cant_v = [], [], []
    s = 0.0
    hand = 1.0
    while s < length_m + 50.0:
        k = hand / 3000.0
        for el in (Line(400.0), Clothoid(200.0, 0.0, k), Arc(600.0, k), Clothoid(200.0, k, 0.0)):
            elements.append(el)
        cant_s += [s + 400.0, s + 600.0, s + 1200.0, s + 1400.0]
        cant_v += [0.0, hand * 0.08, hand * 0.08, 0.0]
        s += 1400.0
        hand = -hand
    elements.append(Line(100.0))
    h = HorizontalAlignment.from_elements(500000.0, 3100000.0, 0.5, elements)
    pvi = np.arange(0.0, s + 100.0 + 1e-9, 500.0)
    pvi[-1] = min(pvi[-1], s + 100.0)
    heights = 50.0 + 2.0 * np.sin(pvi / 1500.0)
    curve = np.full(pvi.size, 150.0)
    curve[[0, -1]] = 0.0
    return Alignment(h, VerticalProfile.from_pvis(pvi, heights, curve),
                     CantProfile.from_stations(cant_s, cant_v))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--length-m", type=float, default=10000.0)
    ap.add_argument("--rate-hz", type=float, default=200.0)
    args = ap.parse_args()
    alignment = long_alignment(args.length_m)
    cfg = SimulationConfig(length_m=args.length_m, imu_rate_hz=args.rate_hz)

    t0 = time.perf_counter()
    sim = simulate_survey(alignment, cfg)
    t_sim = time.perf_counter() - t0
    n = sim.session.imu_t_s.size

    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    floor = np.cumsum(rng.standard_normal((n, 6)), axis=0)
    t_floor = time.perf_counter() - t0
    del floor

    tmp = Path(tempfile.mkdtemp(prefix="bench_simulate_"))
    try:
        t0 = time.perf_counter()
        write_session(tmp / "s", sim.session, None)
        t_write = time.perf_counter() - t0
        t0 = time.perf_counter()
        write_truth_csv(tmp / "truth.csv", sim.truth)
        t_truth = time.perf_counter() - t0
        size = sum(p.stat().st_size for p in (tmp / "s").iterdir())
        t0 = time.perf_counter()
        back = read_session(tmp / "s")
        t_read = time.perf_counter() - t0
        assert back.imu_t_s.size == n
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    print(f"survey: {args.length_m:.0f} m, {sim.truth.motion.duration_s:.0f} s, "
          f"{n} IMU samples at {args.rate_hz:g} Hz, {len(sim.session.fixes)} fixes")
    print(f"floor (draw + cumsum {n}x6 normals): {t_floor:.2f} s")
    print(f"simulate:           {t_sim:6.2f} s  ({t_sim / t_floor:.1f} x floor, "
          f"{1e6 * t_sim / n:.2f} us/sample)")
    print(f"write session:      {t_write:6.2f} s  ({size / 1e6:.0f} MB, {1e6 * t_write / n:.2f} us/row)")
    print(f"write truth.csv:    {t_truth:6.2f} s")
    print(f"read session:       {t_read:6.2f} s  ({1e6 * t_read / n:.2f} us/row)")


if __name__ == "__main__":
    main()
