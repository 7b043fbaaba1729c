"""(d) The resection/fix chain checked link by link against independent computations.

python benchmarks/fix_sigma/audit_d.py
"""
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from common import TwinMeter
from drivers import geocom as gc
from trolley.resection import (InstrumentSigmas, PolarModel, PolarObservations, ResectionConfig, ResectionError,
                               observation_jacobian, observations_from_station, point_from_observation, reduce_to_grid,
                               resect)

ST = np.array([500300.0, 3100350.0, 51.5])
ORI = 1.2345


def layout(n_pairs=4, heading=math.radians(60.0)):
    fwd, right = np.array([math.sin(heading), math.cos(heading)]), np.array([math.cos(heading), -math.sin(heading)])
    pts, ids = [], []
    for k in range(n_pairs):
        s = (k - (n_pairs - 1) / 2) * 60.0
        for side, sg in (("L", -1), ("R", 1)):
            en = ST[:2] + s * fwd + sg * 2.75 * right + 3.0 * right
            pts.append([*en, ST[2] - 1.2 + 0.3 * k])
            ids.append(f"C{k}{side}")
    return ids, np.array(pts)


print("1. observation_jacobian against central differences (grid scale 1.0004, c&r on):")
m = PolarModel(grid_scale=1.0004)
p = ST + [150.0, 200.0, 3.0]
J = observation_jacobian(ST, p, m)[0]
num = np.zeros((3, 3))
for j in range(3):
    h = np.zeros(3)
    h[j] = 1e-3
    a = observations_from_station(ST, 0.0, p + h, m).as_array()[0]
    b = observations_from_station(ST, 0.0, p - h, m).as_array()[0]
    num[:, j] = (a - b) / 2e-3
print(f"   max relative difference {np.max(np.abs(J - num)) / np.max(np.abs(J)):.2e}")

print("2. degenerate geometry:")
ids, pts = layout()
cfg = ResectionConfig(model=PolarModel(curvature_refraction=False))
rng = np.random.default_rng(1)
sig = InstrumentSigmas()


def noisy(o):
    return PolarObservations(o.hz_rad + rng.normal(0, sig.direction_rad, len(o)),
                             o.zenith_rad + rng.normal(0, sig.zenith_rad, len(o)),
                             o.slope_distance_m + rng.normal(0, 6e-4, len(o)))


def attempt(label, ids_, pts_, obs_):
    try:
        r = resect(ids_, pts_, obs_, cfg)
        s = r.station_sigma_m
        print(f"   {label}: ACCEPTED, station sigma E {s[0]*1e3:.3g} N {s[1]*1e3:.3g} H {s[2]*1e3:.3g} mm, orientation "
              f"{r.orientation_sigma_rad / math.radians(1/3600):.3g}\", sigma0 {r.sigma0:.2f}, error "
              f"{np.linalg.norm(r.station_enh_m - ST) * 1e3:.3g} mm")
    except ResectionError as e:
        print(f"   {label}: refused ({e})")


one = np.repeat(pts[:1], 3, axis=0)
attempt("three ids at one prism (same coordinates)", ["A", "B", "C"], one, noisy(observations_from_station(ST, ORI, one)))
# directions and zenith angles only, the 4 points on one circle through the station (the danger circle)
ang = np.deg2rad([20.0, 80.0, 150.0, 230.0])
centre = ST[:2] + [0.0, 60.0]
circ = np.column_stack([centre[0] + 60 * np.sin(ang), centre[1] - 60 * np.cos(ang), np.full(4, ST[2])])
o = observations_from_station(ST, ORI, circ)
o_dir = noisy(o)
o_dir = PolarObservations(o_dir.hz_rad, o_dir.zenith_rad, np.full(4, np.nan))
attempt("directions only, 4 points on a circle through the station", list("PQRS"), circ, o_dir)
attempt("directions only, 4 points well spread (control)", list("PQRS"),
        np.column_stack([ST[0] + 60 * np.sin(ang), ST[1] + 60 * np.cos(ang), np.full(4, ST[2])]),
        PolarObservations(*noisy(observations_from_station(
            ST, ORI, np.column_stack([ST[0] + 60 * np.sin(ang), ST[1] + 60 * np.cos(ang), np.full(4, ST[2])])
        )).as_array()[:, :2].T, np.full(4, np.nan)))
line = np.column_stack([ST[0] + np.array([30.0, 60, 90]) * 0.5, ST[1] + np.array([30.0, 60, 90]) * 0.866, np.full(3, ST[2])])
attempt("3 points on one ray from the station, with distances", list("XYZ"), line,
        noisy(observations_from_station(ST, ORI, line)))

print("3. orientation across 0 / 2 pi (noise-free, 8 CPIII):")
for ori in (1e-9, 2 * math.pi - 1e-9, math.pi):
    r = resect(ids, pts, observations_from_station(ST, ori, pts, cfg.model), cfg)
    d = (r.orientation_rad - ori + math.pi) % (2 * math.pi) - math.pi
    print(f"   true {ori:.10f}: station error {np.abs(r.station_enh_m - ST).max() * 1e9:.3g} nm, orientation error {d:.2e} rad")

print("4. the session's fix chain through the twin's GeoCOM (no noise): grid scale and heights")
c = (1 - 0.13) / (2 * 6.378e6)
prisms = {d: ST + [d * math.sin(math.radians(60)), d * math.cos(math.radians(60)), -0.6] for d in (20.0, 60.0, 100.0, 260.0)}


def chain(k, cr):
    """Twin sees ground distances (grid offset / k) and an apparent height (lowered by c hd^2 if cr)."""
    cc = c if cr else 0.0
    meter = TwinMeter(0.0, 0.0)
    try:
        meter.place(ST, ORI)

        def seen(x):
            d = x - ST
            hd = math.hypot(d[0], d[1]) / k
            return ST + [d[0] / k, d[1] / k, d[2] - cc * hd * hd]

        m = np.array([meter.measure(seen(x), [0]) for x in pts])
        model = PolarModel(grid_scale=k, curvature_refraction=cr)
        r = resect(ids, pts, PolarObservations(*m.T), ResectionConfig(model=model))
        ts = meter.ts
        ts.distance = None  # the instrument refuses TMC_SetStation while it holds a distance (rc 1293)
        # what stationsetup._give_station does
        assert ts.handle(gc.Request(gc.TMC_SETSTATION, None, (*r.station_enh_m, 0.0), False, True))[0] == 0
        hz = ts.handle(gc.Request(gc.TMC_GETANGLE5, None, (), False, True))[1][0]
        ts.distance = None
        assert ts.handle(gc.Request(gc.TMC_SETORIENTATION, None, ((hz + r.orientation_rad) % (2 * math.pi),), False, True))[0] == 0
        out = {}
        for dd, x in prisms.items():
            meter.measure(seen(x), [1])
            e, n, h = ts._coords()
            hz_, v_, sd_ = ts.distance
            via_coord = reduce_to_grid(r.station_enh_m, [e, n, h], k)          # what grid_coordinates does
            via_polar = point_from_observation(r.station_enh_m, 0.0, PolarObservations(hz_, v_, sd_), model)[0]
            out[dd] = (via_coord - x, via_polar - x)
        return r, out
    finally:
        meter.close()


for k, cr in ((1.0, False), (0.99961, False), (1.00001, False), (1.0, True), (0.99961, True)):
    r, out = chain(k, cr)
    print(f"   grid scale {k}, c&r {'on' if cr else 'off'}: station error {np.abs(r.station_enh_m - ST).max()*1e6:.2f} um")
    for dd, (a, b) in out.items():
        print(f"      prism at {dd:5.0f} m: GetCoordinate + reduce_to_grid error E {a[0]*1e3:+.3f} N {a[1]*1e3:+.3f} "
              f"H {a[2]*1e3:+.3f} mm | from the polar readings with the setup's model E {b[0]*1e3:+.3f} "
              f"N {b[1]*1e3:+.3f} H {b[2]*1e3:+.3f} mm")
