"""The setup error's effect on the track's error/sigma, separated from the luck of one noise draw.

python benchmarks/fix_sigma/audit_c_draws.py M DEMO_OUT [DEMO_OUT ...]

On each demo session's own IMU/odometer data and fix times, M draws of the fixes:
  A  truth + N(0, fix sigma) per axis                      (no setup error), sigma 0.6 mm
  B  truth + J_k delta_s + N(0, fix sigma), delta_s ~ N(0, C_s) once per setup s (shared by its fixes),
     sigma 0.6 mm                                           (what the session does now)
  C  the fixes of B, sigma^2 = 0.6^2 + diag(J C_s J^T)      (the honest per-fix sigma)
C_s is the stored setup's resection covariance, J = [I3 | (dN, -dE, 0)] at each fix.
Pooled over draws and sessions: RMS lateral/vertical (mm), RMS error/sigma lateral/vertical, fixes rejected.
"""
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from common import setups_of_demo
from survey.session.simworld import prism_position_enh
from survey.sessionio import read_design, read_session
from trolley.engine import ProcessConfig, process_session
from trolley.session import Fixes
from trolley.validation import track_errors

M = int(sys.argv[1])
acc = {k: [] for k in "ABC"}
for out in map(Path, sys.argv[2:]):
    store, sid, world, setups = setups_of_demo(out)
    sim, truth = world.sim, world.sim.truth
    by_id = {s.setup_id: s for s, *_ in setups}
    sig = store.settings().fix_sigma_m
    acc_fixes = sorted(store.fixes(sid, accepted_only=True), key=lambda f: f.t_s)
    session = read_session(out / "session")
    design = read_design(out / "session", session.meta, [])
    t = np.array([f.t_s for f in acc_fixes])
    assert np.allclose(np.sort(session.fixes.t_s), t, atol=1e-6)
    P = np.array([prism_position_enh(sim, x) for x in t])
    sids = np.array([f.setup_id for f in acc_fixes])
    J = np.zeros((len(t), 3, 4))
    J[:, :, :3] = np.eye(3)
    for i, f in enumerate(acc_fixes):
        d = P[i] - by_id[f.setup_id].station_enh_m
        J[i, 0, 3], J[i, 1, 3] = d[1], -d[0]
    Cs = np.array([J[i] @ by_id[s].covariance @ J[i].T for i, s in enumerate(sids)])
    honest = np.sqrt(sig ** 2 + np.diagonal(Cs, axis1=1, axis2=2))
    labels = np.array([f.point for f in acc_fixes], dtype=object)
    for m in range(M):
        rng = np.random.default_rng([4242, m])
        noise = rng.standard_normal(P.shape) * sig
        delta = {s: rng.multivariate_normal(np.zeros(4), by_id[s].covariance) for s in np.unique(sids)}
        setup_err = np.array([J[i] @ delta[s] for i, s in enumerate(sids)])
        runs = {"A": (P + noise, np.full(P.shape, sig)), "B": (P + setup_err + noise, np.full(P.shape, sig)),
                "C": (P + setup_err + noise, honest)}
        for k, (enh, sg) in runs.items():
            res = process_session(replace(session, fixes=Fixes(t, labels, enh, sg)), design, ProcessConfig())
            tj = res.trajectory
            e = track_errors(tj.t_s, tj.distance_m, tj.enh_m, tj.sigma_enh_m, truth, cov_EN_m2=tj.cov_EN_m2)
            acc[k].append((e.lateral_m if hasattr(e, "lateral_m") else None, e, res.summary["fixes_rejected"]))
        print(f"{out.name} draw {m}: " + "  ".join(
            f"{k} lat e/s {acc[k][-1][1].normalised_rms()[0]:.2f}" for k in "ABC"), flush=True)

print(f"\npooled over {M} draws x {len(sys.argv) - 2} sessions (mean squares pooled over the samples):")
for k in "ABC":
    es = [x[1] for x in acc[k]]
    ms = np.mean([np.square(e.rms_m()) for e in es], axis=0)
    nr = np.mean([np.square(e.normalised_rms()) for e in es], axis=0)
    rej = sum(x[2] for x in acc[k])
    per = np.array([e.normalised_rms()[0] for e in es])
    print(f"{k}: RMS lat {np.sqrt(ms[0]) * 1e3:.3f} vert {np.sqrt(ms[2]) * 1e3:.3f} lon {np.sqrt(ms[1]) * 1e3:.3f} mm"
          f" | RMS e/s lat {np.sqrt(nr[0]):.3f} vert {np.sqrt(nr[2]):.3f} | per-run lat e/s 5-95 % "
          f"{np.percentile(per, 5):.2f}-{np.percentile(per, 95):.2f} | fixes rejected {rej}")
