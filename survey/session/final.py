"""The end of a field session: the whole session re-processed from the store, sheet and plots written.

The stored session (accepted fixes only) is exported to a raw session folder (FORMATS.md section 1),
so the final track is exactly what ``trolley process`` gives on that folder; the track is stored as
the session's "final" processing run.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from survey.store import ProjectStore, TrackResult


def cropped_session(raw, t0_s: float):
    """The session without the samples before ``t0_s`` (a restarted static alignment)."""
    if t0_s is None or not np.isfinite(t0_s) or raw.imu_t_s.size == 0 or t0_s <= raw.imu_t_s[0]:
        return raw
    i = raw.imu_t_s >= t0_s
    o = raw.odo_t_s >= t0_s
    g = None if raw.gauge_t_s is None else raw.gauge_t_s >= t0_s
    f = raw.fixes.t_s >= t0_s
    fx = replace(raw.fixes, t_s=raw.fixes.t_s[f], point=raw.fixes.point[f], enh_m=raw.fixes.enh_m[f],
                 sigma_m=raw.fixes.sigma_m[f])
    return replace(raw, imu_t_s=raw.imu_t_s[i], imu_w_rad_s=raw.imu_w_rad_s[i], imu_f_m_s2=raw.imu_f_m_s2[i],
                   odo_t_s=raw.odo_t_s[o], odo_distance_m=raw.odo_distance_m[o], fixes=fx,
                   gauge_t_s=None if g is None else raw.gauge_t_s[g], gauge_m=None if g is None else raw.gauge_m[g])


def track_result(stations) -> TrackResult:
    """Engine stations as stored track rows."""
    st = stations
    return TrackResult(st.chainage_m, np.column_stack([st.E_m, st.N_m, st.H_m]),
                       np.column_stack([st.sigma_E_m, st.sigma_N_m, st.sigma_H_m]), st.lateral_dev_m,
                       st.vertical_dev_m, st.gauge_m, st.cant_m, st.twist_m)


def process_stored_session(store: ProjectStore, name: str, out_dir: Path, static_start_s, outcome, console,
                           tolerances: str | None = None):
    """Export, process, store the final track, write the Excel sheet and the plots.

    Returns the ``outcome`` with its paths filled in.
    """
    from survey.commands.engine import run_process
    from survey.export import export_outputs
    from survey.sessionio import write_session

    out_dir = Path(out_dir)
    raw, xml = store.raw_session(name)
    raw = cropped_session(raw, static_start_s)
    session_dir = out_dir / "session"
    raw = replace(raw, meta=replace(raw.meta, design_alignment="alignment.xml" if xml else None))
    console.print("end of session: exporting the raw session, re-processing it (filter + RTS smoother) ...")
    write_session(session_dir, raw, xml, overwrite=True)
    result, _, written = run_process(session_dir, out_dir / "processed")
    rec = store.session(name)
    st = result.stations
    store.add_track(rec.session_id, "final", float(raw.imu_t_s[0]), float(raw.imu_t_s[-1]), track_result(st))
    kw = {} if tolerances is None else {"tolerances": tolerances}
    exported = export_outputs(out_dir / "processed", out_dir / "survey.xlsx", None, out_dir / "plots", **kw)
    outcome.session_dir = session_dir
    outcome.track_csv = written.track_csv
    outcome.xlsx = exported.xlsx
    outcome.plots_dir = out_dir / "plots"
    outcome.result = result
    return outcome
