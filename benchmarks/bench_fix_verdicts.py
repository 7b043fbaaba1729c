"""Which fixes the engine uses: the forward gate and the data snooping (docs/engine.md, "Fixes
rejected one after another, and data snooping").

Simulated surveys with the demo project's settings (1.2 km, fixes every 60 m). Part 1: correct
fixes only, for each IMU grade and seed: fixes rejected, taken back by the snooping, the longest
run of rejected fixes, and the RMS lateral / vertical error with its RMS error/sigma against the
truth. Part 2: runs of wrong fixes (one bad station setup measuring several stops, moved east by
the same amount): the fixes rejected, against the ones moved. The figures are accuracy, not speed;
the seconds per run are printed for scale only. Part 3 (``--random N``): for each IMU and seed,
N runs of 1-3 wrong fixes at random places, moved together by 5-30 times a rough 1-sigma of one
interval's prediction (RLG/FOG 3 mm, MEMS 40 mm) in a random direction: how often exactly the
wrong ones are rejected, how many wrong fixes are used and right ones rejected.

    python benchmarks/bench_fix_verdicts.py [--imu mems] [--seeds 0-35] [--no-wrong] [--random 6]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from survey.commands.simulate import project_settings
from trolley.engine import ProcessConfig, process_session
from trolley.landxml import parse_landxml
from trolley.sensors import IMU_PRESETS
from trolley.truthsim import SimulationConfig, simulate_survey
from trolley.validation import track_errors

ROOT = Path(__file__).resolve().parents[1]
#: (IMU, seed, metres east, fixes moved): the cases of docs/engine.md
WRONG_RUNS = [
    ("rlg", 0, 0.05, (5, 6, 7)), ("rlg", 0, 0.01, (5, 6, 7)), ("rlg", 3, 0.03, (10, 11, 12)),
    ("rlg", 0, 0.02, (3,)), ("fog", 1, 0.05, (2, 3, 4)), ("mems", 0, 0.1, (5, 6, 7)),
    ("mems", 0, 0.5, (5, 6, 7)), ("mems", 5, 0.3, (10, 11, 12)), ("mems", 7, 0.2, (3, 4, 5)),
]


#: rough 1-sigma of one interval's prediction, the unit of the random wrong fixes of part 3
RANDOM_SCALE_M = {"rlg": 0.003, "fog": 0.003, "mems": 0.04}


def seed_range(text: str) -> range:
    first, _, last = text.partition("-")
    return range(int(first), int(last or first) + 1)


def run(design, kwargs, imu: str, seed: int, moved_east_m: float = 0.0, moved=()):
    sim = simulate_survey(design, SimulationConfig(**{**kwargs, "imu": IMU_PRESETS[imu], "seed": seed}))
    sim.session.fixes.enh_m[list(moved), 0] += moved_east_m
    t0 = time.perf_counter()
    r = process_session(sim.session, design, ProcessConfig(), with_observability=False)
    return sim, r, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--imu", nargs="+", default=["rlg", "fog", "mems"], choices=sorted(IMU_PRESETS))
    ap.add_argument("--seeds", default="0-11", help="first-last, e.g. 0-35")
    ap.add_argument("--no-correct", action="store_true", help="skip part 1")
    ap.add_argument("--no-wrong", action="store_true", help="skip part 2")
    ap.add_argument("--random", type=int, default=0, metavar="N", help="part 3: N random runs of wrong fixes per seed")
    args = ap.parse_args()
    kwargs, _, xml = project_settings(ROOT / "projects" / "demo")
    design = parse_landxml(xml)

    if not args.no_correct:
        print("part 1: correct fixes only")
        print(f"{'imu':5s} {'seed':>4s} {'rej':>4s} {'back':>5s} {'run':>4s}   lateral rms mm (e/s)   "
              "vertical rms mm (e/s)    s")
    for imu in [] if args.no_correct else args.imu:
        cascades = 0
        for seed in seed_range(args.seeds):
            sim, r, dt = run(design, kwargs, imu, seed)
            tj = r.trajectory
            e = track_errors(tj.t_s, tj.distance_m, tj.enh_m, tj.sigma_enh_m, sim.truth, cov_EN_m2=tj.cov_EN_m2)
            s = r.summary
            cascades += s["longest_rejected_run"] >= 3
            cols = []
            for err, sig in ((e.lateral_m, e.sigma_lateral_m), (e.vertical_m, e.sigma_vertical_m)):
                cols.append(f"{1e3 * np.sqrt(np.mean(err**2)):8.2f} ({np.sqrt(np.mean((err / sig) ** 2)):.2f})")
            print(f"{imu:5s} {seed:4d} {s['fixes_rejected']:4d} {s.get('fixes_readmitted', 0):5d} "
                  f"{s['longest_rejected_run']:4d}   {cols[0]:>20s}   {cols[1]:>20s} {dt:5.1f}", flush=True)
        print(f"{imu}: {cascades} surveys with 3 or more fixes rejected in a row")

    if not args.no_wrong:
        print("\npart 2: runs of wrong fixes (moved east together)")
        for imu, seed, east, moved in WRONG_RUNS:
            _, r, _ = run(design, kwargs, imu, seed, east, moved)
            rejected = [int(i) for i in np.flatnonzero(~r.fixes.accepted)]
            verdict = "exactly the moved ones" if rejected == list(moved) else "DIFFERENT"
            print(f"{imu:5s} seed {seed:2d}: fixes {list(moved)} moved {1e3 * east:5.0f} mm east -> rejected "
                  f"{rejected} ({verdict})", flush=True)
    if args.random:
        print(f"\npart 3: {args.random} random runs of 1-3 wrong fixes per seed")
        for imu in args.imu:
            exact = total = used = lost = 0
            for seed in seed_range(args.seeds):
                sim = simulate_survey(design, SimulationConfig(**{**kwargs, "imu": IMU_PRESETS[imu], "seed": seed}))
                rng = np.random.default_rng(1000 + seed)
                m = len(sim.session.fixes.t_s)
                clean = sim.session.fixes.enh_m.copy()
                for k in range(args.random):
                    n = 1 + k % 3
                    start = int(rng.integers(1, m - n))
                    size = rng.uniform(5, 30) * RANDOM_SCALE_M[imu]
                    ang = rng.uniform(0, 2 * np.pi)
                    moved = list(range(start, start + n))
                    sim.session.fixes.enh_m[:] = clean
                    direction = np.array([np.cos(ang), np.sin(ang), rng.uniform(-0.5, 0.5)])
                    sim.session.fixes.enh_m[moved] += direction * size
                    r = process_session(sim.session, design, ProcessConfig(), with_observability=False)
                    rejected = set(np.flatnonzero(~r.fixes.accepted).tolist())
                    total += 1
                    exact += rejected == set(moved)
                    used += len(set(moved) - rejected)
                    lost += len(rejected - set(moved))
                    if rejected != set(moved):
                        print(f"{imu:5s} seed {seed:2d}: fixes {moved} moved {1e3 * size:.1f} mm -> rejected "
                              f"{sorted(rejected)}", flush=True)
            print(f"{imu}: exactly the wrong ones rejected in {exact} of {total}; wrong fixes used {used}, "
                  f"right fixes rejected {lost}", flush=True)


if __name__ == "__main__":
    main()
