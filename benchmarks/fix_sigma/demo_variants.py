"""The demo's accuracy split into the two changes of overlap24: the overlap fix kept, the sigma0 scaling.

python benchmarks/fix_sigma/demo_variants.py DEMO_OUT [DEMO_OUT ...]

Re-processes each demo's raw session (DEMO_OUT/session, recorded with both changes) with
trolley.engine.process_session, as `trolley process` does, the fixes.csv varied:
  recorded          as the session wrote it: the overlap fix within 3 sigma kept, the setup covariance
                    in each fix sigma scaled by max(1, sigma0^2)
  a priori sigma    the same fixes, the setup covariance not scaled (the fix sigma before overlap24)
  no overlap fixes  the fixes that an overlap check outside the tolerance let in left out (as before
                    overlap24), sigmas as recorded
and prints RMS lateral / vertical / longitudinal (mm) and RMS error/sigma lateral / vertical against the
simulator's truth, as the demo does.
"""
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from common import setups_of_demo, track_figures
from survey.sessionio import read_design, read_session
from trolley.resection import fix_covariance, overlap_check
from trolley.session import Fixes

for out in map(Path, sys.argv[1:]):
    store, sid, world, setups = setups_of_demo(out)
    truth = world.sim.truth
    instrument = store.settings().instrument
    tol = store.settings().overlap_tolerance_m
    by_id = {s.setup_id: s for s, *_ in setups}
    stored = sorted(store.fixes(sid), key=lambda f: (f.t_s, f.fix_id))
    acc = [f for f in stored if f.accepted]
    # the overlap fixes outside the tolerance that the session kept (main rejected them)
    kept_outside = set()
    for i, f in enumerate(stored):
        if f.accepted and f.reason.startswith("overlap check"):
            old = next(g for g in reversed(stored[:i]) if g.accepted and g.setup_id != f.setup_id)
            oc = overlap_check(f.point, [old.e_m, old.n_m, old.h_m], [f.e_m, f.n_m, f.h_m], tol)
            if not oc.within_tolerance:
                kept_outside.add(f.point)
    session = read_session(out / "session")
    design = read_design(out / "session", session.meta, [])
    fx = session.fixes
    order = np.argsort(fx.t_s, kind="stable")
    fx = Fixes(fx.t_s[order], np.asarray(fx.point, dtype=object)[order], fx.enh_m[order], fx.sigma_m[order])
    assert list(fx.point) == [f.point for f in acc]
    apriori = np.array([np.sqrt(np.diag(fix_covariance(instrument, by_id[f.setup_id].covariance,
                                                       by_id[f.setup_id].station_enh_m, [f.e_m, f.n_m, f.h_m])[0]))
                        for f in acc])
    keep = np.array([p not in kept_outside for p in fx.point])
    variants = {
        "recorded": fx,
        "a priori sigma": replace(fx, sigma_m=apriori),
        "no overlap fixes": Fixes(fx.t_s[keep], fx.point[keep], fx.enh_m[keep], fx.sigma_m[keep]),
    }
    print(f"{out}: {len(acc)} accepted fixes; kept outside the tolerance: {', '.join(sorted(kept_outside)) or '-'}; "
          f"sigma0 of the setups {', '.join(f'{s.sigma0:.2f}' for s in by_id.values())}; the fix sigmas scaled "
          f"vs a priori: up to {np.max(fx.sigma_m / apriori):.4f}")
    for name, f in variants.items():
        rms, nr, s = track_figures(session, design, f, truth)
        print(f"   {name:17s} RMS lateral {rms[0]:.3f} vertical {rms[2]:.3f} longitudinal {rms[1]:.3f} mm | "
              f"error/sigma lateral {nr[0]:.2f} vertical {nr[2]:.2f} | fixes used/rejected "
              f"{s['fixes_used']}/{s['fixes_rejected']}", flush=True)
