"""The overlap check at a station change: how often a correct overlap is refused, before and after overlap24.

python benchmarks/fix_sigma/overlap_false_alarms.py DEMO_OUT [N]   (DEMO_OUT: a `trolley demo --out` folder:
the geometry of its station changes, the physical stations, circle orientations and the 8 CPIII each
measured, and the trolley's prism at each overlap stop)

For each of the demo's station changes, N times: both setups resected from the total-station twin's
readings (its own noise code, as audit_a.py), the prism at the overlap stop carried through each setup's
station and orientation errors, plus the twin's fix noise N(0, 0.6 mm) per axis on each measurement;
the difference new minus old goes through trolley.resection.overlap_check with each fix's sigma as the
session computes it (fix_covariance with Resection.setup_covariance, diagonal as stored) and through the
session's decision (survey.session.stationsetup.overlap_kept). Counted:
  before    refused when outside the tolerance (2 mm on some axis), as main did
  after     refused only outside the tolerance and beyond 3 sigma on some axis (overlap_kept)
and the rate of OUTSIDE verdicts, of differences beyond 3 sigma, and RMS d/sigma per axis (1 when the
sigma is honest). Then the same with a blunder added to the new measurement (H, then E): the share of
blunders each rule refuses. The live gate the session also applies is not modelled here.
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
from trolley.resection import PolarObservations, fix_covariance, overlap_check, resect, wrap_to_pi

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
    """(position of P measured from a fresh resection of setup k, its 3x3 covariance as the session has it)."""
    s, station, orient, ids, pts = setups[k]
    meter.place(station, orient)
    m = np.array([meter.measure(p, [trial, k, i, 11]) for i, p in enumerate(pts)])
    r = resect(ids, pts, PolarObservations(m[:, 0], m[:, 1], m[:, 2]), config)
    dth = float(wrap_to_pi(r.orientation_rad - orient))
    v = P - station
    c, sn = math.cos(dth), math.sin(dth)
    setup_err = (r.station_enh_m - station) + np.array([v[0] * c + v[1] * sn - v[0], -v[0] * sn + v[1] * c - v[1], 0])
    fix = P + setup_err + rng.standard_normal(3) * sig
    return fix, np.diag(np.diag(fix_covariance(sig, r.setup_covariance, r.station_enh_m, fix)[0])), r.sigma0


try:
    rows = []
    for label, k_old, k_new, P in pairs:
        for trial in range(N):
            a, ca, s0a = one_setup(k_old, trial, P)
            b, cb, s0b = one_setup(k_new, trial, P)
            oc = overlap_check(label, a, b, tol, ca, cb)
            blunder = {}
            for axis in (2, 0):
                for mm in BLUNDERS_MM:
                    bb = b.copy()
                    bb[axis] += mm * 1e-3 * (1 if rng.random() < 0.5 else -1)
                    ob = overlap_check(label, a, bb, tol, ca, cb)
                    blunder[(axis, mm)] = (not ob.within_tolerance, not overlap_kept(ob))
            rows.append((label, oc.difference_enh_m / oc.sigma_enh_m, not oc.within_tolerance, not overlap_kept(oc),
                         oc.consistent is False, oc.sigma_enh_m, blunder))
finally:
    meter.close()


def rate(x):
    x = np.asarray(x, dtype=float)
    n, k = x.size, int(x.sum())
    # Clopper-Pearson 95 % interval
    lo = stats.beta.ppf(0.025, k, n - k + 1) if k > 0 else 0.0
    hi = stats.beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return f"{100 * k / n:5.2f} % [{100 * lo:.2f}, {100 * hi:.2f}]"


print(f"{N} trials per station change; fix noise {sig * 1e3:.2f} mm per axis; tolerance {tol * 1e3:.1f} mm; "
      f"twin setup noise {o.angle_sigma_rad:.3g} rad, {o.distance_sigma_m * 1e3:.2f} mm")
for label in [p[0] for p in pairs] + ["all"]:
    R = [r for r in rows if label in ("all", r[0])]
    z = np.array([r[1] for r in R])
    s = np.array([r[5] for r in R]) * 1e3
    print(f"\n{label} ({len(R)} correct overlaps): sigma of the difference E/N/H {s[:, 0].mean():.3f} / "
          f"{s[:, 1].mean():.3f} / {s[:, 2].mean():.3f} mm; RMS d/sigma " +
          " / ".join(f"{np.sqrt(np.mean(z[:, j] ** 2)):.3f}" for j in range(3)))
    # analytic, the axes taken as independent (the E-N correlation of the orientation part is small here)
    p_tol = 1 - np.prod(1 - 2 * stats.norm.sf(tol * 1e3 / s.mean(axis=0)))
    p_3s = 1 - (1 - 2 * stats.norm.sf(3.0)) ** 3
    print(f"   OUTSIDE the tolerance (both):      {rate([r[2] for r in R])}   analytic {100 * p_tol:.2f} %")
    print(f"   beyond 3 sigma on some axis:       {rate([r[4] for r in R])}   analytic {100 * p_3s:.2f} %")
    print(f"   fix refused, before (tolerance):   {rate([r[2] for r in R])}")
    print(f"   fix refused, after (tol. and 3 sigma): {rate([r[3] for r in R])}")
print("\nblunders on the new measurement (all station changes): share refused, before / after")
for axis in (2, 0):
    for mm in BLUNDERS_MM:
        b = [r[6][(axis, mm)] for r in rows]
        print(f"   {'ENH'[axis]} {mm:.1f} mm: before {rate([x[0] for x in b])}   after {rate([x[1] for x in b])}")
