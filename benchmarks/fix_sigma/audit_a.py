"""(a) The resection's reported covariance against a Monte Carlo of the total-station twin's noise.

python benchmarks/fix_sigma/audit_a.py DEMO_OUT [N]   (DEMO_OUT: a `trolley demo --out` folder, for the
geometry of its four setups: the physical station, the circle orientation, the 8 CPIII measured)
"""
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).parent))
from common import TwinMeter, setups_of_demo, std_ratio_ci
from trolley.resection import PolarObservations, resect, wrap_to_pi

out = Path(sys.argv[1])
N = int(sys.argv[2]) if len(sys.argv) > 2 else 1000
store, sid, world, setups = setups_of_demo(out)
settings = store.settings()
o = world.options
print(f"twin noise: angle {o.angle_sigma_rad:.4g} rad ({o.angle_sigma_rad / math.radians(1 / 3600):.4f}\"), "
      f"distance {o.distance_sigma_m * 1e3:.3f} mm; resection a priori: direction/zenith "
      f"{settings.instrument.direction_rad:.4g} rad, distance {settings.instrument.distance_m * 1e3:.3f} mm "
      f"+ {settings.instrument.distance_scale * 1e6:g} ppm")

variants = {
    # what a simulated session does: the twin measures in the grid, no curvature (stationsetup.new_station)
    "session (k=1, no c&r)": dict(k=1.0, cr=False),
    # a real site: ground distances on a grid with combined scale k, and Earth curvature + refraction;
    # the twin is made to see them by moving its target (horizontal offset / k, height lowered by c hd^2)
    "grid k=0.99961, c&r on": dict(k=0.99961, cr=True),
    # the resection weighted with the twin's own sigmas (no ppm part, 2.4e-6 rad): the propagation alone
    "session, a priori = twin's sigmas": dict(k=1.0, cr=False, own=True),
}
meter = TwinMeter(o.angle_sigma_rad, o.distance_sigma_m)
names = ["E", "N", "H", "orient"]
try:
    for vname, v in variants.items():
        print(f"\n=== {vname}, {N} trials per setup ===")
        model = replace(settings.polar_model, grid_scale=v["k"], curvature_refraction=v["cr"])
        config = replace(settings.resection_config(None), model=model)
        if v.get("own"):
            from trolley.resection import InstrumentSigmas
            config = replace(config, sigmas=InstrumentSigmas(o.angle_sigma_rad, o.angle_sigma_rad, o.distance_sigma_m, 0.0))
        c = model.height_drop_per_m2
        pooled_maha = []
        for k, (s, station, orient, ids, pts) in enumerate(setups):
            meter.place(station, orient)
            d = pts - station
            hd_ground = np.hypot(d[:, 0], d[:, 1]) / v["k"]
            seen = station + np.column_stack([d[:, 0] / v["k"], d[:, 1] / v["k"], d[:, 2] - c * hd_ground ** 2])
            errs, covs, s0 = [], None, []
            t0 = time.perf_counter()
            for trial in range(N):
                m = np.array([meter.measure(seen[i], [trial, k, i, 99]) for i in range(len(ids))])
                r = resect(ids, pts, PolarObservations(m[:, 0], m[:, 1], m[:, 2]), config)
                e = np.r_[r.station_enh_m - station, wrap_to_pi(r.orientation_rad - orient)]
                errs.append(e)
                covs = r.covariance if covs is None else covs
                s0.append(r.sigma0)
            errs = np.array(errs)
            dt = time.perf_counter() - t0
            sig = np.sqrt(np.diag(covs))
            dist = np.hypot(d[:, 0], d[:, 1])
            print(f"setup {k}: {len(ids)} points at {dist.min():.0f}-{dist.max():.0f} m; reported sigma "
                  f"E {sig[0] * 1e3:.4f} N {sig[1] * 1e3:.4f} H {sig[2] * 1e3:.4f} mm, orientation "
                  f"{sig[3] / math.radians(1 / 3600):.4f}\"  ({dt:.0f} s)")
            for j in range(4):
                rr, lo, hi = std_ratio_ci(errs[:, j], sig[j])
                bias = errs[:, j].mean() / (sig[j] / math.sqrt(N))
                print(f"   {names[j]:6s} MC std / reported sigma {rr:.3f}  [95% CI {lo:.3f}, {hi:.3f}]   "
                      f"mean / (sigma/sqrt N) {bias:+.2f}")
            rho_rep = covs / np.outer(sig, sig)
            rho_mc = np.corrcoef(errs.T)
            print("   correlation reported vs MC (E-N, E-or, N-or, H-or): " + ", ".join(
                f"{rho_rep[a, b]:+.3f}/{rho_mc[a, b]:+.3f}" for a, b in [(0, 1), (0, 3), (1, 3), (2, 3)]))
            maha = np.einsum("ij,jk,ik->i", errs, np.linalg.inv(covs), errs)
            pooled_maha.append(maha)
            print(f"   Mahalanobis e' C^-1 e: mean {maha.mean():.3f} (chi2(4): 4), share > chi2_4(0.99) "
                  f"{np.mean(maha > stats.chi2.ppf(0.99, 4)) * 100:.2f} % (1 %); mean sigma0^2 {np.mean(np.square(s0)):.3f}")
        pm = np.concatenate(pooled_maha)
        lo, hi = stats.chi2.ppf([0.025, 0.975], 4 * pm.size) / pm.size
        print(f"pooled over setups: mean Mahalanobis {pm.mean():.3f}, 95% band for an honest covariance "
              f"[{lo:.3f}, {hi:.3f}]")
finally:
    meter.close()
