"""The end of a field session: the whole session re-processed from the store, sheet and plots written.

The stored session (accepted fixes only, cropped at the static alignment that succeeded:
``survey.store.ProjectStore.raw_session``, the same as ``trolley project export-session``) is
exported to a raw session folder (FORMATS.md section 1), so the final track is exactly what
``trolley process`` gives on that folder; the track is stored as the session's "final" processing run.
The store's record of the crew's decisions (every fix with its reason, the station setups, the
overlap checks, the stops, the survey header) goes beside track.csv as ``field_record.json``
(survey/fieldrecord.py), which the sheet reads.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from survey.store import ProjectStore, TrackResult


def track_result(stations) -> TrackResult:
    """Engine stations as stored track rows."""
    st = stations
    return TrackResult(st.chainage_m, np.column_stack([st.E_m, st.N_m, st.H_m]),
                       np.column_stack([st.sigma_E_m, st.sigma_N_m, st.sigma_H_m]), st.lateral_dev_m,
                       st.vertical_dev_m, st.gauge_m, st.cant_m, st.twist_m)


def process_stored_session(store: ProjectStore, name: str, out_dir: Path, outcome, console, tolerances: str):
    """Export, process, store the final track, write the Excel sheet and the plots.

    ``tolerances``: the tolerance set of the sheet, resolved once for the session
    (:func:`survey.session.interval.tolerance_set_name`), the same as the live interval summaries.
    Returns the ``outcome`` with its paths filled in.
    """
    from survey.atomicwrite import remove_stale_temporaries
    from survey.commands.engine import run_process
    from survey.export import export_outputs
    from survey.sessionio import write_session

    out_dir = Path(out_dir)
    # a final processing killed half-way left hidden temporaries of its outputs: this run replaces them
    remove_stale_temporaries(out_dir, ("survey.xlsx",))
    remove_stale_temporaries(out_dir / "plots", None)
    remove_stale_temporaries(out_dir / "processed", None)
    session_dir = out_dir / "session"
    # and a raw session folder it was writing (sessionio.write_session builds it beside, then renames)
    import shutil

    for partial in out_dir.glob(f".{session_dir.name}.*.partial"):
        shutil.rmtree(partial, ignore_errors=True)
    raw, xml = store.raw_session(name)
    raw = replace(raw, meta=replace(raw.meta, design_alignment="alignment.xml" if xml else None))
    console.print("end of session: exporting the raw session, re-processing it (filter + RTS smoother) ...")
    write_session(session_dir, raw, xml, overwrite=True)
    from survey.session.fieldsession import CREW_ACCEPTED

    # the fixes the crew accepted despite the live innovation test stay accepted: neither the
    # engine's gate nor its data snooping may overrule the crew
    crew = tuple(f.point for f in store.fixes(store.session(name).session_id, accepted_only=True)
                 if f.reason == CREW_ACCEPTED)
    result, _, written = run_process(session_dir, out_dir / "processed", force_accept=crew,
                                     project_name=store.info().name, session_name=name)
    rec = store.session(name)
    st = result.stations
    from survey.fieldrecord import field_record, write_field_record

    # the crew's rejected and undone fixes, the setups and the overlap checks, for the sheet
    write_field_record(out_dir / "processed", field_record(store, name))
    exported = export_outputs(out_dir / "processed", out_dir / "survey.xlsx", None, out_dir / "plots",
                              tolerances=tolerances, project_name=store.info().name, session_name=name)
    # stored last: the "final" run is what tells a resume that the end is done, so a kill before
    # the sheet and the plots are written makes the resume do the whole end again
    store.add_track(rec.session_id, "final", float(raw.imu_t_s[0]), float(raw.imu_t_s[-1]), track_result(st))
    outcome.session_dir = session_dir
    outcome.track_csv = written.track_csv
    outcome.xlsx = exported.xlsx
    outcome.plots_dir = out_dir / "plots"
    outcome.plots = list(exported.plots)
    outcome.result = result
    return outcome
