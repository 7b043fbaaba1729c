"""(b) at scale: fix error / fix sigma over many simulated setups, split by distance to the station.

python benchmarks/fix_sigma/audit_b_mc.py DEMO_OUT N

The demo's four setups (physical station, circle orientation, the 8 CPIII it measured) are resected
N times each from the total-station twin's readings (its own noise code, as in audit_a.py); each
resection's station and orientation errors are carried to the true prism positions of the fixes the
demo took from that setup (exactly as the session's chain does it: audit_b.py shows the setup part of
every recorded fix equal to this to 0.003 um), and the twin's fix noise N(0, 0.6 mm) per axis is added.
Per axis: RMS(error / sigma) with sigma = the 0.6 mm written before (fixes.csv on main) and the
sigma with the setup covariance propagated (fixsig24), with 95 % chi-square intervals.
"""
import math
import sys
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).parent))
from common import TwinMeter, setups_of_demo
from survey.session.simworld import prism_position_enh
from trolley.resection import PolarObservations, resect, setup_covariance_at, wrap_to_pi
from dataclasses import replace

out, N = Path(sys.argv[1]), int(sys.argv[2])
store, sid, world, setups = setups_of_demo(out)
sim = world.sim
o = world.options
sig = store.settings().fix_sigma_m
config = settings_config = store.settings().resection_config(None)
config = replace(config, model=replace(config.model, curvature_refraction=False))
fixes = store.fixes(sid)
meter = TwinMeter(o.angle_sigma_rad, o.distance_sigma_m)
rng = np.random.default_rng(77)
Z0, Z1, D, ZS = [], [], [], []
try:
    for k, (s, station, orient, ids, pts) in enumerate(setups):
        P = np.array([prism_position_enh(sim, f.t_s) for f in fixes if f.setup_id == s.setup_id])
        dist = np.hypot(*(P[:, :2] - station[:2]).T)
        meter.place(station, orient)
        for trial in range(N):
            m = np.array([meter.measure(p, [trial, k, i, 5]) for i, p in enumerate(pts)])
            r = resect(ids, pts, PolarObservations(m[:, 0], m[:, 1], m[:, 2]), config)
            dth = float(wrap_to_pi(r.orientation_rad - orient))
            v = P - station
            c, sn = math.cos(dth), math.sin(dth)
            setup_err = (r.station_enh_m - station) + np.column_stack(
                [v[:, 0] * c + v[:, 1] * sn - v[:, 0], -v[:, 0] * sn + v[:, 1] * c - v[:, 1], np.zeros(len(v))])
            fix = P + setup_err + rng.standard_normal(P.shape) * sig
            Cs = setup_covariance_at(r.covariance, r.station_enh_m, fix)
            honest = np.sqrt(sig ** 2 + np.diagonal(Cs, axis1=1, axis2=2))
            err = fix - P
            Z0.append(err / sig)
            Z1.append(err / honest)
            ZS.append(setup_err / np.sqrt(np.diagonal(Cs, axis1=1, axis2=2)))
            D.append(dist)
finally:
    meter.close()
Z0, Z1, ZS, D = (np.concatenate(x) for x in (Z0, Z1, ZS, D))


def ci(z):
    n = z.size
    r = math.sqrt(np.mean(z ** 2))
    lo, hi = np.sqrt(stats.chi2.ppf([0.025, 0.975], n) / n)
    return f"{r:.3f} [{r / hi:.3f}, {r / lo:.3f}]"


print(f"{N} setups x 4 geometries, {Z0.shape[0]} fixes; fix noise {sig * 1e3:.2f} mm per axis; the setups' 8 CPIII at "
      f"20-140 m")
for lo, hi in [(0, 50), (50, 150), (150, 300), (0, 300)]:
    m = (D >= lo) & (D < hi)
    print(f"{lo:3d}-{hi:3d} m (n={m.sum()}, mean {D[m].mean():.0f} m):")
    for j, a in enumerate("ENH"):
        print(f"   {a}: RMS err/sigma  sigma 0.6 mm {ci(Z0[m, j])}   sigma with setup {ci(Z1[m, j])}   "
              f"setup part / its sigma {ci(ZS[m, j])}")
