"""(b) The fix sigma in fixes.csv against the fixes' actual errors (truth: the simulated prism).

python benchmarks/fix_sigma/audit_b.py DEMO_OUT [DEMO_OUT ...]

Per fix: error = stored fix - simulated prism (simworld.prism_position_enh at the fix time). The
twin's fix noise is seeded by (seed, stop, attempt), so it is reproduced here and subtracted: what
is left is the error the station setup put into the fix, compared with (i) its direct value from the
resected minus the physical station and orientation (the chain's geometry, to the micrometre) and
(ii) the resection covariance propagated by J = [I3 | (dN, -dE, 0)].
"""
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from common import setups_of_demo
from survey.session.simworld import prism_position_enh, stop_index_at
from trolley.resection import setup_covariance_at


def setup_cov_at(cov4, station, point):
    """The setup's covariance carried to one point (3, 3)."""
    return setup_covariance_at(cov4, station, point)[0]


rows = []
for out in map(Path, sys.argv[1:]):
    store, sid, world, setups = setups_of_demo(out)
    sim = world.sim
    sig_fix = store.settings().fix_sigma_m
    by_id = {s.setup_id: (s, st, orient) for s, st, orient, _, _ in setups}
    attempts = {}
    fixes = sorted(store.fixes(sid), key=lambda f: (f.t_s, f.fix_id))
    for f in fixes:
        k = stop_index_at(sim, f.t_s)
        a = attempts.get(k, 0)
        attempts[k] = a + 1
        noise = np.random.default_rng([world.options.seed, k + 1, a]).standard_normal(3) * sig_fix
        truth = prism_position_enh(sim, f.t_s)
        fix = np.array([f.e_m, f.n_m, f.h_m])
        err = fix - truth
        s, st_true, orient_true = by_id[f.setup_id]
        d_st = s.station_enh_m - st_true
        dth = (s.orientation_rad - orient_true + math.pi) % (2 * math.pi) - math.pi
        v = truth - st_true
        c, sn = math.cos(dth), math.sin(dth)
        # the instrument reads azimuths off by dth (clockwise): the offset turned by dth about the station
        pred = d_st + np.array([v[0] * c + v[1] * sn - v[0], -v[0] * sn + v[1] * c - v[1], 0.0])
        C = setup_cov_at(s.covariance, s.station_enh_m, fix)
        rows.append(dict(run=out.name, fix=f.point, acc=f.accepted, dist=float(np.hypot(v[0], v[1])),
                         err=err, noise=noise, setup_err=err - noise, pred=pred, sig=np.array([f.sigma_e_m, f.sigma_n_m, f.sigma_h_m]),
                         Csetup=C, sig_fix=sig_fix))

R = rows
print(f"{len(R)} fixes from {len(sys.argv) - 1} runs (all measured fixes, accepted or not)")
geo = np.array([r["setup_err"] - r["pred"] for r in R])
print(f"setup part of the error (error - reproduced fix noise) minus its direct value from the resected - physical "
      f"station and orientation: max |.| {np.abs(geo).max() * 1e6:.3f} um (E, N, H)")
E = np.array([r["err"] for r in R])
S = np.array([np.full(3, r["sig_fix"]) for r in R])  # the 0.6 mm fixes.csv had before fixsig24
Sh = np.array([np.sqrt(r["sig_fix"] ** 2 + np.diag(r["Csetup"])) for r in R])
D = np.array([r["dist"] for r in R])
SE = np.array([r["setup_err"] for r in R])
SS = np.array([np.sqrt(np.diag(r["Csetup"])) for r in R])
bins = [(0, 50), (50, 150), (150, 300)]


def line(label, m):
    z = E[m] / S[m]
    zh = E[m] / Sh[m]
    zs = SE[m] / SS[m]
    n = int(m.sum())
    print(f"{label:>12s} n={n:3d} dist {D[m].mean():5.0f} m | RMS err/sigma(0.6 mm) E {np.sqrt(np.mean(z[:, 0]**2)):.2f} "
          f"N {np.sqrt(np.mean(z[:, 1]**2)):.2f} H {np.sqrt(np.mean(z[:, 2]**2)):.2f} | err/sigma(with setup) "
          f"E {np.sqrt(np.mean(zh[:, 0]**2)):.2f} N {np.sqrt(np.mean(zh[:, 1]**2)):.2f} H {np.sqrt(np.mean(zh[:, 2]**2)):.2f}"
          f" | setup err/setup sigma E {np.sqrt(np.mean(zs[:, 0]**2)):.2f} N {np.sqrt(np.mean(zs[:, 1]**2)):.2f} "
          f"H {np.sqrt(np.mean(zs[:, 2]**2)):.2f} | setup sigma mm E {SS[m, 0].mean()*1e3:.3f} N {SS[m, 1].mean()*1e3:.3f} H {SS[m, 2].mean()*1e3:.3f}")


line("all", np.ones(len(R), bool))
for lo, hi in bins:
    line(f"{lo}-{hi} m", (D >= lo) & (D < hi))
