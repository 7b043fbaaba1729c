"""Throughput of design-geometry evaluation and projection (points per second).

Evaluates the demo design (``projects/demo/alignment.xml``) at 1e6 random chainages and
projects 1e6 points scattered up to +-5 m around it, and prints each against a floor
measured in the same run: ``np.sin`` on the same number of points (the cost of one
transcendental per point). Best of ``--repeat`` runs. Also prints the projection round-trip
error (evaluate -> offset along the normal -> project).

Run: ``python benchmarks/bench_alignment.py [--n 1000000] [--repeat 3]``.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from trolley.landxml import parse_landxml

REPO = Path(__file__).resolve().parents[1]


def best_time(fn, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    al = parse_landxml((REPO / "projects" / "demo" / "alignment.xml").read_text(encoding="utf-8"))
    rng = np.random.default_rng(2026)
    s = rng.uniform(al.start_chainage_m, al.end_chainage_m, args.n)
    d = rng.uniform(-5.0, 5.0, args.n)
    r = al.evaluate(s)
    E = r.E_m + d * np.cos(r.heading_rad)
    N = r.N_m - d * np.sin(r.heading_rad)

    t_floor = best_time(lambda: np.sin(s), args.repeat)
    t_eval = best_time(lambda: al.evaluate(s), args.repeat)
    t_proj = best_time(lambda: al.project(E, N, r.H_m), args.repeat)
    p = al.project(E, N, r.H_m)
    err_s = float(np.max(np.abs(p.chainage_m - s)))
    err_d = float(np.max(np.abs(p.lateral_m - d)))

    n = args.n
    print(f"points: {n}, best of {args.repeat}")
    print(f"floor  np.sin        {n / t_floor:12.3e} points/s  ({t_floor * 1e3:8.1f} ms)")
    print(f"Alignment.evaluate   {n / t_eval:12.3e} points/s  ({t_eval * 1e3:8.1f} ms)  "
          f"= {t_eval / t_floor:6.1f} x floor")
    print(f"Alignment.project    {n / t_proj:12.3e} points/s  ({t_proj * 1e3:8.1f} ms)  "
          f"= {t_proj / t_floor:6.1f} x floor")
    print(f"round trip: max |ds| = {err_s:.2e} m, max |dd| = {err_d:.2e} m")


if __name__ == "__main__":
    main()
