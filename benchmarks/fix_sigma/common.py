"""Shared helpers of the fix-sigma audit scripts (docs/field_session.md, "The fix sigma and the
station setup"): the demo's setups read back from its store, the twin's noise, ratio intervals."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from scipy import stats

from drivers import geocom as gc
from drivers.twins.totalstation import TotalStationTwin


def demo_store(out: Path):
    from survey.store import ProjectStore
    return ProjectStore.open(Path(out) / "project" / "demo" / "project.sqlite")


def setups_of_demo(out: Path):
    """[(setup record, physical station (3,), true circle orientation, point ids, points (n,3))]
    of a demo run, from its store (the simulated_instrument events give where the twin stood)."""
    from survey.commands.survey import simulated_world

    store = demo_store(out)
    sid = store.session("demo").session_id
    world = simulated_world(store, 1.0)
    station0 = world.station_enh_m.copy()
    moves = {0: station0}
    for e in store.events(sid):
        if e.kind == "simulated_instrument":
            d = json.loads(e.detail)
            moves[int(d["setup"])] = np.array(d["station_enh_m"])
    cp = {p.point_id: np.array([p.e_m, p.n_m, p.h_m]) for p in store.cpiii_points()}
    out_rows = []
    setups = [s for s in store.station_setups(sid) if s.accepted]
    for k, s in enumerate(setups):
        obs = [o for o in store.setup_observations(s.setup_id) if o.used]
        ids = [o.point_id for o in obs]
        orient = (world.options.orientation_rad + 0.37 * k) % (2 * math.pi)
        out_rows.append((s, moves[k], orient, ids, np.array([cp[i] for i in ids])))
    return store, sid, world, out_rows


class TwinMeter:
    """Polar readings through the total-station twin's own code (its noise model, its geometry)."""

    def __init__(self, angle_sigma_rad: float, dist_sigma_m: float) -> None:
        self.ts = TotalStationTwin(station=(0, 0, 0, 0), target=None, noise_angle_rad=angle_sigma_rad,
                                   noise_dist_m=dist_sigma_m, seed=0)

    def place(self, station, orientation):
        self.ts.position = tuple(map(float, station))
        self.ts.orientation = float(orientation)

    def measure(self, target, seed) -> tuple[float, float, float]:
        ts = self.ts
        ts.seed_noise(seed)
        ts.set_target(tuple(map(float, target)))
        ts.handle(gc.Request(rpc=gc.AUT_FINEADJUST, params=(), trid=None, crc_present=False, crc_ok=True))
        ts._measure_distance()
        return ts.distance

    def close(self):
        try:
            self.ts.stop()
        except Exception:
            pass


def std_ratio_ci(err: np.ndarray, sigma: float, conf: float = 0.95):
    """MC std / sigma with its chi-square confidence interval (zero-mean not assumed)."""
    n = err.size
    s = float(np.std(err, ddof=1))
    lo = math.sqrt(stats.chi2.ppf((1 - conf) / 2, n - 1) / (n - 1))
    hi = math.sqrt(stats.chi2.ppf((1 + conf) / 2, n - 1) / (n - 1))
    r = s / sigma
    return r, r / hi, r / lo


def track_figures(session, design, fixes, truth):
    """The session processed with these fixes against the truth: RMS lateral, longitudinal,
    vertical error in mm, their RMS error/sigma, and the engine's summary."""
    from dataclasses import replace

    from trolley.engine import ProcessConfig, process_session
    from trolley.validation import track_errors

    res = process_session(replace(session, fixes=fixes), design, ProcessConfig())
    tj = res.trajectory
    e = track_errors(tj.t_s, tj.distance_m, tj.enh_m, tj.sigma_enh_m, truth, cov_EN_m2=tj.cov_EN_m2)
    return np.array(e.rms_m()) * 1e3, e.normalised_rms(), res.summary
