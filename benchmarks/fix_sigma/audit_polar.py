"""Fix error / fix sigma at short and long sightings: the isotropic fix_sigma_m against the polar covariance.

python benchmarks/fix_sigma/audit_polar.py [N] [matched]   (default 2000 trials per case; 20 s per 1000)

A free station beside a straight track (north), 8 CPIII in pairs 3 m left and right of it at -90, -30,
+30, +90 m; a trolley prism on the track 20 m and 250 m ahead. Each trial resects the station from the
total-station twin's own readings (its noise code: 0.495" on Hz and V, 0.6 mm on the distance, no
ppm) and measures the prism through the twin as well, the point computed from the readings with the
resected station and orientation (trolley.resection.point_from_observation, as the session does).
Error = that point minus the true prism. Sigmas per axis:
  before    sqrt(fix_sigma_m^2 + diag(setup part scaled by max(1, sigma0^2)))  (fix_sigma_m 0.6 mm; main)
  after     sqrt(diag(fix_covariance(a priori sigmas, setup, factor)))        (the polar covariance, scaled)
  unscaled  the same with the polar part not scaled by the variance factor
against the project's a priori sigmas (0.5", 0.6 mm + 1 ppm; with ``matched`` the twin's own, 0.495",
0.6 mm, no ppm), with the twin at 1x and at 2x those
readings' noise (an instrument worse than its datasheet: sigma0 about 2). Printed: RMS(error / sigma)
per axis E / N / H with the 95 % chi-square interval (1 when the sigma is honest), and the mean of
e' C^-1 e with the full 3x3 covariance (3 when honest).
"""
import math
import sys
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).parent))
from common import TwinMeter
from trolley.resection import (InstrumentSigmas, PolarModel, PolarObservations, ResectionConfig, fix_covariance,
                               point_from_observation, resect, setup_covariance_at, variance_factor)

N = int(sys.argv[1]) if len(sys.argv) > 1 else 2000
FIX_SIGMA_M = 0.0006
TWIN_ANGLE_RAD, TWIN_DIST_M = 2.4e-6, 0.0006  # survey.session.simworld.SimOptions
MATCHED = len(sys.argv) > 2 and sys.argv[2] == "matched"
APRIORI = (InstrumentSigmas(TWIN_ANGLE_RAD, TWIN_ANGLE_RAD, TWIN_DIST_M, 0.0) if MATCHED else InstrumentSigmas())
MODEL = PolarModel(curvature_refraction=False)  # the twin measures grid distances without curvature
CONFIG = ResectionConfig(sigmas=APRIORI, model=MODEL)
STATION = np.array([1000.0, 5000.0, 51.2])
ORIENT = 1.2345
IDS = [f"CP{i}" for i in range(8)]
CPIII = np.array([[STATION[0] + side, STATION[1] + n, 50.5 + 0.3 * side / 3.0]
                  for n in (-90.0, -30.0, 30.0, 90.0) for side in (-3.0, 3.0)])


def ci(z: np.ndarray) -> str:
    n = z.size
    r = math.sqrt(np.mean(z**2))
    lo, hi = np.sqrt(stats.chi2.ppf([0.025, 0.975], n) / n)
    return f"{r:.3f} [{r / hi:.3f}, {r / lo:.3f}]"


def run(distance_m: float, ratio: float):
    meter = TwinMeter(ratio * TWIN_ANGLE_RAD, ratio * TWIN_DIST_M)
    meter.place(STATION, ORIENT)
    prism = STATION + [3.0, distance_m, -0.6]
    err, s_before, s_after, s_unscaled, nees = [], [], [], [], []
    try:
        for trial in range(N):
            m = np.array([meter.measure(p, [trial, i, int(distance_m), int(10 * ratio)]) for i, p in enumerate(CPIII)])
            r = resect(IDS, CPIII, PolarObservations(*m.T), CONFIG)
            f = variance_factor(r.sigma0, r.dof)
            hz, v, sd = meter.measure(prism, [trial, 99, int(distance_m), int(10 * ratio)])
            p = point_from_observation(r.station_enh_m, r.orientation_rad, PolarObservations(hz, v, sd), MODEL)[0]
            setup = setup_covariance_at(r.covariance, r.station_enh_m, p)[0]
            c = fix_covariance(APRIORI, r.covariance, r.station_enh_m, p, MODEL, f)[0]
            e = p - prism
            err.append(e)
            s_before.append(np.sqrt(FIX_SIGMA_M**2 + f * np.diag(setup)))
            s_after.append(np.sqrt(np.diag(c)))
            s_unscaled.append(np.sqrt(np.diag(c - f * setup) / f + f * np.diag(setup)))
            nees.append(e @ np.linalg.solve(c, e))
    finally:
        meter.close()
    return tuple(np.array(x) for x in (err, s_before, s_after, s_unscaled, nees))


print(f"{N} trials per case; twin reading noise {TWIN_ANGLE_RAD:.3g} rad (Hz, V), {TWIN_DIST_M * 1e3:.2f} mm "
      f"(times the ratio); a priori {'the twin' if MATCHED else '0.5, 0.6 mm + 1 ppm'}; before: fix_sigma_m {FIX_SIGMA_M * 1e3:.1f} mm per axis")
for ratio in (1.0, 2.0):
    for dist in (20.0, 250.0):
        e, sb, sa, su, nees = run(dist, ratio)
        print(f"\nprism {dist:.0f} m ahead, twin noise {ratio:g} x: RMS error E/N/H "
              + " / ".join(f"{x:.3f}" for x in 1e3 * np.sqrt(np.mean(e**2, axis=0))) + " mm; sigma after "
              + " / ".join(f"{x:.3f}" for x in 1e3 * np.sqrt(np.mean(sa**2, axis=0))) + " mm")
        for name, s in (("before", sb), ("after", sa), ("unscaled", su)):
            print(f"   {name:9s} RMS err/sigma E {ci(e[:, 0] / s[:, 0])}  N {ci(e[:, 1] / s[:, 1])}  "
                  f"H {ci(e[:, 2] / s[:, 2])}")
        lo, hi = stats.chi2.ppf([0.025, 0.975], 3 * N) / N
        print(f"   after: mean e' C^-1 e {np.mean(nees):.3f} (honest 3, 95 % [{lo:.3f}, {hi:.3f}])")
