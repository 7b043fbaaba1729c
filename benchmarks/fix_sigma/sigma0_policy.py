"""Which setup covariance is honest when the instrument is noisier (or quieter) than its a priori sigmas.

python benchmarks/fix_sigma/sigma0_policy.py DEMO_OUT [N]   (DEMO_OUT: a `trolley demo --out` folder, for the
geometry of its four setups: the physical station, the circle orientation, the 8 CPIII measured)

Each setup is resected N times from readings whose noise is r times the project's a priori sigmas
(direction, zenith, distance with its ppm part), for several r. Four covariances are compared:
the a priori one, the a priori scaled by sigma0^2 only when the global test of the variance factor
rejects (dof sigma0^2 above the chi-square 95 % point on the redundancy, one-sided), scaled by
max(1, sigma0^2) (``trolley.resection.variance_factor``, what the session uses), and always scaled
by sigma0^2. Honest means that the
mean of e^2 / sigma^2 per component (E, N, H, orientation) is 1; with an estimated variance factor it
is dof / (dof - 2) at best (e and sigma0 are independent, e / sigma is Student-t; 1.111 for dof 20).
The setup's error carried to a fix 230 m away (setup_covariance_at) is reported as well.
"""
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).parent))
from common import setups_of_demo
from trolley.resection import (InstrumentSigmas, observations_from_station, PolarObservations, resect,
                               setup_covariance_at, wrap_to_pi)

out = Path(sys.argv[1])
N = int(sys.argv[2]) if len(sys.argv) > 2 else 1000
ALPHA = 0.05
store, sid, world, setups = setups_of_demo(out)
settings = store.settings()
config = settings.resection_config(None)
# a simulated session's model: the twin measures grid distances with no curvature (stationsetup.polar_model)
config = replace(config, model=replace(config.model, curvature_refraction=False, grid_scale=1.0))
a_priori = config.sigmas
rng = np.random.default_rng(20261127)


def policies(cov, s0, dof):
    crit = stats.chi2.ppf(1 - ALPHA, dof)
    return {
        "a priori": cov,
        "test 5 %": cov * (s0 ** 2 if dof * s0 ** 2 > crit else 1.0),
        "max(1, s0^2)": cov * max(1.0, s0 ** 2),
        "always s0^2": cov * s0 ** 2,
    }


print(f"a priori: direction/zenith {a_priori.direction_rad:.4g} rad, distance {a_priori.distance_m * 1e3:.2f} mm "
      f"+ {a_priori.distance_scale * 1e6:g} ppm; {N} resections per setup and noise ratio; the demo's "
      f"{len(setups)} setups")
for r in (0.7, 1.0, 1.3, 1.5, 2.0, 3.0):
    noise = InstrumentSigmas(r * a_priori.direction_rad, r * a_priori.zenith_rad, r * a_priori.distance_m,
                             r * a_priori.distance_scale)
    z2 = {}
    fix_z2 = {}
    rejected = 0
    dofs = []
    for k, (s, station, orient, ids, pts) in enumerate(setups):
        exact = observations_from_station(station, orient, pts, config.model)
        far = station + [230.0 * math.sin(1.0), 230.0 * math.cos(1.0), -0.6]
        for _ in range(N):
            n = len(exact)
            obs = PolarObservations(exact.hz_rad + rng.normal(0, noise.direction_rad, n),
                                    exact.zenith_rad + rng.normal(0, noise.zenith_rad, n),
                                    exact.slope_distance_m + rng.normal(0, 1, n)
                                    * noise.distance_sigma_m(exact.slope_distance_m))
            res = resect(ids, pts, obs, config)
            e = np.r_[res.station_enh_m - station, wrap_to_pi(res.orientation_rad - orient)]
            # the setup's error carried to a point 230 m away: what the fix sigma holds
            d = far - station
            dth = e[3]
            e_fix = e[:3] + np.array([d[1] * dth, -d[0] * dth, 0.0])
            dofs.append(res.dof)
            rejected += res.dof * res.sigma0 ** 2 > stats.chi2.ppf(1 - ALPHA, res.dof)
            for name, c in policies(res.covariance, res.sigma0, res.dof).items():
                z2.setdefault(name, []).append(e ** 2 / np.diag(c))
                cf = setup_covariance_at(c, res.station_enh_m, far)[0]
                fix_z2.setdefault(name, []).append(e_fix ** 2 / np.diag(cf))
    m = len(dofs)
    lo, hi = stats.chi2.ppf([0.025, 0.975], m) / m
    print(f"\nnoise {r:g} x a priori: global test rejects {rejected / m * 100:.1f} % of {m} setups (dof "
          f"{min(dofs)}-{max(dofs)}); mean z^2 E / N / H / orientation, and of the setup error at a fix 230 m away "
          f"E / N / H (honest 1, 95 % band of a chi-square mean [{lo:.3f}, {hi:.3f}]; best possible with an "
          f"estimated factor {np.mean(np.array(dofs) / (np.array(dofs) - 2)):.3f})")
    for name in z2:
        a = np.mean(z2[name], axis=0)
        b = np.mean(fix_z2[name], axis=0)
        print(f"   {name:13s} " + " / ".join(f"{x:6.3f}" for x in a) + "    fix 230 m " +
              " / ".join(f"{x:6.3f}" for x in b))
