"""The overlap check at a station change: how often a correct overlap is refused, per-axis against joint.

python benchmarks/fix_sigma/overlap_false_alarms.py DEMO_OUT [N]   (DEMO_OUT: a `trolley demo --out` folder:
the geometry of its station changes, the physical stations, circle orientations and the 8 CPIII each
measured, and the trolley's prism at each overlap stop)

For each of the demo's station changes, N times: both setups resected from the total-station twin's
readings (its own noise code, as audit_a.py), and the prism at the overlap stop measured through the twin
from each (its reading noise, the point computed from the readings with the resected station and
orientation, as the session does); the difference new minus old. Two sigmas and rules:
  per axis (fixcov25's before)  each fix's sigma sqrt(fix_sigma_m^2 + setup part scaled), the difference
                                refused when outside the tolerance and beyond 3 sigma on some axis
  joint (now)                   each fix's full covariance (trolley.resection.fix_covariance: the polar
                                measurement and the setup, scaled by the variance factor) on the stored
                                sigmas, through overlap_check and the session's decision
                                (survey.session.stationsetup.overlap_kept): Mahalanobis > 3.436
and the rate of OUTSIDE verdicts, RMS d/sigma per axis (1 when the sigma is honest) and the mean of
d' C^-1 d (3). Then a blunder added to the new measurement (H, then E): the share each rule refuses.
The live gate the session also applies is not modelled here.
"""
import math
import sys
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).parent))
from dataclasses import replace

from common import TwinMeter, setups_of_demo
from survey.session.simworld import prism_position_enh
from survey.session.stationsetup import overlap_kept
from trolley.resection import (PolarObservations, fix_covariance, overlap_check, point_from_observation, resect,
                               setup_covariance_at, variance_factor)

out = Path(sys.argv[1])
N = int(sys.argv[2]) if len(sys.argv) > 2 else 2000
store, sid, world, setups = setups_of_demo(out)
sim, o = world.sim, world.options
settings = store.settings()
sig = settings.fix_sigma_m
tol = settings.overlap_tolerance_m
config = settings.resection_config(None)
config = replace(config, model=replace(config.model, curvature_refraction=False, grid_scale=1.0))
fixes = sorted(store.fixes(sid), key=lambda f: (f.t_s, f.fix_id))
pairs = []
for i, f in enumerate(fixes):
    if f.reason.startswith("overlap check"):
        old = next(g for g in reversed(fixes[:i]) if g.accepted and g.setup_id != f.setup_id)
        ks = [k for k, (s, *_) in enumerate(setups) if s.setup_id in (old.setup_id, f.setup_id)]
        pairs.append((f.point, ks[0], ks[1], prism_position_enh(sim, f.t_s)))
meter = TwinMeter(o.angle_sigma_rad, o.distance_sigma_m)
rng = np.random.default_rng(20261128)
BLUNDERS_MM = (2.0, 2.5, 3.0, 4.0, 5.0, 6.0)


def one_setup(k, trial, P):
    """(position of P measured from a fresh resection of setup k, its 3x3 covariance as the session has it,
    its per-axis sigma as fixcov25's before had it)."""
    s, station, orient, ids, pts = setups[k]
    meter.place(station, orient)
    m = np.array([meter.measure(p, [trial, k, i, 11]) for i, p in enumerate(pts)])
    r = resect(ids, pts, PolarObservations(m[:, 0], m[:, 1], m[:, 2]), config)
    fix = point_from_observation(r.station_enh_m, r.orientation_rad,
                                 PolarObservations(*meter.measure(P, [trial, k, 99, 11])), config.model)[0]
    f = variance_factor(r.sigma0, r.dof)
    cov = fix_covariance(settings.instrument, r.covariance, r.station_enh_m, fix, config.model, f)[0]
    old = np.sqrt(sig**2 + f * np.diag(setup_covariance_at(r.covariance, r.station_enh_m, fix)[0]))
    return fix, cov, old


def refused_per_axis(d, s_a, s_b):
    """(outside the tolerance, refused by the per-axis rule: outside and beyond 3 sigma on some axis)."""
    outside = bool(np.any(np.abs(d) > tol))
    return outside, outside and bool(np.any(np.abs(d) > 3.0 * np.hypot(s_a, s_b)))


try:
    rows = []
    for label, k_old, k_new, P in pairs:
        for trial in range(N):
            a, ca, sa = one_setup(k_old, trial, P)
            b, cb, sb = one_setup(k_new, trial, P)
            oc = overlap_check(label, a, b, tol, ca, cb)
            blunder = {}
            for axis in (2, 0):
                for mm in BLUNDERS_MM:
                    bb = b.copy()
                    bb[axis] += mm * 1e-3 * (1 if rng.random() < 0.5 else -1)
                    ob = overlap_check(label, a, bb, tol, ca, cb)
                    blunder[(axis, mm)] = (refused_per_axis(bb - a, sa, sb)[1], not overlap_kept(ob))
            rows.append((label, oc.difference_enh_m / oc.sigma_enh_m, not oc.within_tolerance, not overlap_kept(oc),
                         oc.consistent is False, oc.sigma_enh_m, blunder, refused_per_axis(oc.difference_enh_m, sa, sb)[1],
                         oc.difference_enh_m / np.hypot(sa, sb), oc.mahalanobis ** 2))
finally:
    meter.close()


def rate(x):
    x = np.asarray(x, dtype=float)
    n, k = x.size, int(x.sum())
    # Clopper-Pearson 95 % interval
    lo = stats.beta.ppf(0.025, k, n - k + 1) if k > 0 else 0.0
    hi = stats.beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return f"{100 * k / n:5.2f} % [{100 * lo:.2f}, {100 * hi:.2f}]"


print(f"{N} trials per station change; tolerance {tol * 1e3:.1f} mm; twin reading noise {o.angle_sigma_rad:.3g} rad, "
      f"{o.distance_sigma_m * 1e3:.2f} mm (setups and fixes); per-axis sigma with fix_sigma_m {sig * 1e3:.2f} mm")
for label in [p[0] for p in pairs] + ["all"]:
    R = [r for r in rows if label in ("all", r[0])]
    z = np.array([r[1] for r in R])
    z_old = np.array([r[8] for r in R])
    s = np.array([r[5] for r in R]) * 1e3
    print(f"\n{label} ({len(R)} correct overlaps): sigma of the difference E/N/H {s[:, 0].mean():.3f} / "
          f"{s[:, 1].mean():.3f} / {s[:, 2].mean():.3f} mm; RMS d/sigma joint's " +
          " / ".join(f"{np.sqrt(np.mean(z[:, j] ** 2)):.3f}" for j in range(3)) + ", per-axis's " +
          " / ".join(f"{np.sqrt(np.mean(z_old[:, j] ** 2)):.3f}" for j in range(3)) +
          f"; mean d' C^-1 d {np.mean([r[9] for r in R]):.3f} (3)")
    print(f"   OUTSIDE the tolerance:                  {rate([r[2] for r in R])}")
    print(f"   beyond the joint 3.436:                 {rate([r[4] for r in R])}   analytic 0.81 %")
    print(f"   fix refused, per axis (tol. and 3 sigma, 0.6 mm): {rate([r[7] for r in R])}")
    print(f"   fix refused, joint (tol. and 3.436 joint):        {rate([r[3] for r in R])}")
print("\nblunders on the new measurement (all station changes): share refused, per axis / joint")
for axis in (2, 0):
    for mm in BLUNDERS_MM:
        b = [r[6][(axis, mm)] for r in rows]
        print(f"   {'ENH'[axis]} {mm:.1f} mm: per axis {rate([x[0] for x in b])}   joint {rate([x[1] for x in b])}")
