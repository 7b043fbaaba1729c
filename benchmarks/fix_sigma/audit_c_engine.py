"""What the setup errors and honest fix sigmas do to the processed track of demo sessions.

python benchmarks/fix_sigma/audit_c_engine.py DEMO_OUT [DEMO_OUT ...]

Re-processes each demo's raw session (DEMO_OUT/session) with trolley.engine.process_session, the
fixes.csv varied:
  recorded      the fixes as recorded, sigma = the project's fix sigma (0.6 mm; fixes.csv before fixsig24)
  honest-diag   the fixes as recorded, sigma^2 = fix sigma^2 + diag(J C J^T) (setup propagated; C scaled
                by sigma0^2 when sigma0 > 1, as the session does since overlap24)
  honest-full   the same with the E-N (and E-H, N-H) covariance of the setup part (engine patched; the
                engine takes a fix's whole covariance itself since 2026-11-26, fixes.csv cov_*_m2)
  no-setup-err  the fixes with their setup error removed (truth + the reproduced twin noise), sigma 0.6 mm
and prints RMS lateral / vertical / longitudinal (mm) and RMS error/sigma lateral / vertical, as the demo does.
"""
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import trolley.engine as engine
from common import setups_of_demo, track_figures
from survey.session.simworld import prism_position_enh, stop_index_at
from survey.sessionio import read_design, read_session
from trolley.resection import setup_covariance_at, variance_factor
from trolley.session import Fixes


def setup_cov_at(cov4, station, point):
    """The setup's covariance carried to one point (3, 3)."""
    return setup_covariance_at(cov4, station, point)[0]


_orig_fix_cov = engine.fix_covariances
FULL = {}


def patched_fix_covariances(cov, grid=None):
    R = _orig_fix_cov(cov, grid)
    if "R" in FULL:
        assert FULL["R"].shape == R.shape
        return FULL["R"]
    return R


engine.fix_covariances = patched_fix_covariances

all_rows = []
for out in map(Path, sys.argv[1:]):
    store, sid, world, setups = setups_of_demo(out)
    sim = world.sim
    truth = sim.truth
    by_id = {s.setup_id: s for s, *_ in setups}
    sig_fix = store.settings().fix_sigma_m
    attempts, info = {}, {}
    for f in sorted(store.fixes(sid), key=lambda f: (f.t_s, f.fix_id)):
        k = stop_index_at(sim, f.t_s)
        a = attempts.get(k, 0)
        attempts[k] = a + 1
        noise = np.random.default_rng([world.options.seed, k + 1, a]).standard_normal(3) * sig_fix
        if f.accepted:
            s = by_id[f.setup_id]
            # the covariance the session carried to the fix: scaled by sigma0^2 when sigma0 > 1 (overlap24)
            info[(round(f.t_s, 6), f.point)] = (prism_position_enh(sim, f.t_s) + noise,
                                     setup_cov_at(s.covariance * variance_factor(s.sigma0, s.dof), s.station_enh_m,
                                                  [f.e_m, f.n_m, f.h_m]))
    session = read_session(out / "session")
    design = read_design(out / "session", session.meta, [])
    fx = session.fixes
    order = np.argsort(fx.t_s, kind="stable")
    fx = Fixes(fx.t_s[order], np.asarray(fx.point, dtype=object)[order], fx.enh_m[order], fx.sigma_m[order])
    clean = np.array([info[(round(t, 6), p)][0] for t, p in zip(fx.t_s, fx.point)])
    Cs = np.array([info[(round(t, 6), p)][1] for t, p in zip(fx.t_s, fx.point)])
    honest = np.sqrt(sig_fix ** 2 + np.diagonal(Cs, axis1=1, axis2=2))
    if not np.allclose(fx.sigma_m, sig_fix):  # recorded with overlap24: the sigmas must be these
        assert np.allclose(fx.sigma_m, honest, rtol=1e-9), np.abs(fx.sigma_m / honest - 1).max()
    Rfull = np.zeros_like(Cs)
    P = [1, 0, 2]  # E, N, H -> the filter's N, E, D (D = -H: the E-H and N-H covariances change sign)
    sgn = np.array([1.0, 1.0, -1.0])
    Cfull = Cs + np.eye(3)[None] * sig_fix ** 2
    for i in range(3):
        for j in range(3):
            Rfull[:, i, j] = Cfull[:, P[i], P[j]] * sgn[i] * sgn[j]
    variants = {
        "recorded": (replace(fx, sigma_m=np.full(fx.sigma_m.shape, sig_fix)), None),
        "honest-diag": (replace(fx, sigma_m=honest), None),
        "honest-full": (replace(fx, sigma_m=honest), Rfull),
        "no-setup-err": (replace(fx, enh_m=clean), None),
    }
    for name, (f, R) in variants.items():
        FULL.clear()
        if R is not None:
            FULL["R"] = R
        rms, nr, s = track_figures(session, design, f, truth)
        print(f"{out.name:18s} {name:13s} RMS lat {rms[0]:.3f} vert {rms[2]:.3f} lon {rms[1]:.3f} mm | "
              f"e/s lat {nr[0]:.2f} vert {nr[2]:.2f} | fixes used/rejected {s['fixes_used']}/{s['fixes_rejected']}",
              flush=True)
        all_rows.append((name, rms, nr))

print("\npooled (RMS over runs of the per-run RMS):")
for name in dict.fromkeys(r[0] for r in all_rows):
    rm = np.array([r[1] for r in all_rows if r[0] == name])
    nr = np.array([r[2] for r in all_rows if r[0] == name])
    q = lambda a: np.sqrt(np.mean(a ** 2, axis=0))
    print(f"{name:13s} RMS lat {q(rm)[0]:.3f} vert {q(rm)[2]:.3f} lon {q(rm)[1]:.3f} mm | e/s lat {q(nr)[0]:.2f} "
          f"vert {q(nr)[2]:.2f}")
