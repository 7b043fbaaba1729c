"""Writing the processed track: ``track.csv`` (FORMATS.md section 2), ``fixes.csv``, ``summary.json``.

Conversions to mm happen here, at the edge. The files are written into a temporary folder beside
the output folder, which takes the output folder's place in one rename when all of them are
complete, so a failure never leaves a partial output.
"""
from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from survey import jsonout
from trolley import units
from trolley.engine import ProcessResult
from trolley.session import RawSession
from trolley.stationing import Stationing

from survey.fieldrecord import FIELD_RECORD
from survey.sessionio import move_into_place, write_csv_columns
from survey.sheet_text import csv_safe_text
from survey.track_reader import equipment_figures

TRACK_COLUMNS = ["chainage_m", "E_m", "N_m", "H_m", "sigma_E_mm", "sigma_N_mm", "sigma_H_mm",
                 "lateral_dev_mm", "vertical_dev_mm", "gauge_mm", "cant_mm", "twist_mm", "distance_m",
                 "cov_EN_mm2", "sigma_cant_mm"]
FIX_COLUMNS = ["t_s", "point", "E_m", "N_m", "H_m", "innov_E_mm", "innov_N_mm", "innov_H_mm",
               "nis", "accepted", "reason"]


@dataclass(frozen=True)
class WrittenOutputs:
    """Paths of the files :func:`write_outputs` produced."""

    track_csv: Path
    fixes_csv: Path
    summary_json: Path


def track_frame(result: ProcessResult, stationing: Stationing | None = None) -> pd.DataFrame:
    """The stations as the ``track.csv`` table (mm at the edge).

    ``chainage_m`` is the drawing stationing (after the design's station equations, when
    ``stationing`` is given); ``distance_m`` the internal station (start station plus the
    distance along the design) that the engine works in.
    """
    s = result.stations
    mm = units.m_to_mm
    chainage = s.chainage_m if stationing is None else stationing.station(s.chainage_m)
    return pd.DataFrame({
        "chainage_m": chainage, "E_m": s.E_m, "N_m": s.N_m, "H_m": s.H_m,
        "sigma_E_mm": mm(s.sigma_E_m), "sigma_N_mm": mm(s.sigma_N_m), "sigma_H_mm": mm(s.sigma_H_m),
        "lateral_dev_mm": mm(s.lateral_dev_m), "vertical_dev_mm": mm(s.vertical_dev_m),
        "gauge_mm": mm(s.gauge_m), "cant_mm": mm(s.cant_m), "twist_mm": mm(s.twist_m),
        "distance_m": s.chainage_m,
        "cov_EN_mm2": mm(mm(s.cov_EN_m2)) if s.cov_EN_m2 is not None else np.nan,
        "sigma_cant_mm": mm(s.sigma_cant_m) if s.sigma_cant_m is not None else np.nan,
    }, columns=TRACK_COLUMNS)


def write_track_csv(path: Path, result: ProcessResult, stationing: Stationing | None = None) -> None:
    """``track.csv`` (FORMATS.md section 2): the bytes of ``track_frame(result, stationing).to_csv(path,
    index=False, float_format="%.6f", na_rep="")``, written four times faster (one % per row)."""
    frame = track_frame(result, stationing)
    write_csv_columns(path, list(frame.columns), [frame[c].to_numpy(dtype=float) for c in frame.columns],
                      ["%.6f"] * frame.shape[1], nan_as_empty=True)


def fixes_frame(result: ProcessResult) -> pd.DataFrame:
    """Every fix with its innovation and the gate's verdict."""
    f = result.fixes
    mm = units.m_to_mm
    return pd.DataFrame({
        "t_s": f.t_s, "point": [csv_safe_text(p) for p in f.point],
        "E_m": f.enh_m[:, 0], "N_m": f.enh_m[:, 1], "H_m": f.enh_m[:, 2],
        "innov_E_mm": mm(f.innovation_enh_m[:, 0]), "innov_N_mm": mm(f.innovation_enh_m[:, 1]),
        "innov_H_mm": mm(f.innovation_enh_m[:, 2]), "nis": f.nis,
        "accepted": f.accepted.astype(int), "reason": [csv_safe_text(r) for r in f.reason],
    }, columns=FIX_COLUMNS)


def summary_dict(result: ProcessResult, session: RawSession, session_dir: Path, *,
                 project_name: str | None = None, session_name: str | None = None) -> dict:
    """The run summary that the export and the terminal show.

    Parameters
    ----------
    result, session : the processing result and the raw session it came from.
    session_dir : the raw session folder.
    project_name, session_name : the names the Summary sheet shows. The raw session format
        (FORMATS.md section 1) does not carry them, so callers that know them (the field
        session: project store and session name) pass them; otherwise the session is named
        after its folder and the project is left empty ("" = not given) rather than guessed
        from the parent folder.
    """
    imu = session.meta.imu
    s = result.summary
    folder = Path(session_dir).resolve()
    return {
        "session_dir": str(folder),
        "project": project_name or "",
        "session": session_name or folder.name,
        "imu": {
            "name": imu.name,
            "gyro_bias_instability_deg_h": float(units.rad_s_to_deg_h(imu.gyro_bias_instability_rad_s)),
            "gyro_arw_deg_sqrt_h": float(units.rad_sqrt_s_to_deg_sqrt_h(imu.gyro_arw_rad_sqrt_s)),
        },
        "equipment": equipment_figures(session.meta),
        "smoother": result.config.smoother,
        "fixes_used": s["fixes_used"],
        "fixes_rejected": s["fixes_rejected"],
        "longest_rejected_run": s["longest_rejected_run"],
        "fixes_readmitted": s["fixes_readmitted"],
        "fixes_snooped_out": s["fixes_snooped_out"],
        "rms_innovation_mm": units.m_to_mm(s["rms_innovation_m"]),
        "max_sigma_mm": units.m_to_mm(s["max_sigma_m"]),
        "step_m": result.config.step_m,
        "rail_spacing_m": session.meta.trolley.rail_spacing_m,
        "nominal_gauge_m": session.meta.trolley.nominal_gauge_m,
        "heading_source": s["heading_source"],
        "initial_heading_deg": s["initial_heading_deg"],
        "heading_sigma_deg": s["heading_sigma_deg"],
        "observability_ranks": list(result.observability_ranks) if result.observability_ranks else None,
        "filter_nodes": result.node_count,
        "stations": int(len(result.stations.chainage_m)),
        "crs": s.get("crs"),
        "vertical_datum": s.get("vertical_datum"),
        "grid_scale_factor": s.get("grid_scale_factor"),
        "grid_combined_scale": s.get("grid_combined_scale"),
        "grid_convergence_deg": s.get("grid_convergence_deg"),
    }


OUTPUT_NAMES = ("track.csv", "fixes.csv", "summary.json")
#: what a processed folder may hold besides OUTPUT_NAMES and is replaced with them: the field
#: session's record of the crew's decisions, which the session's end writes beside track.csv after
#: processing (survey.session.final) and rewrites from the store on every run
COMPANION_NAMES = (FIELD_RECORD,)


class OutputFolderError(ValueError):
    """The output folder cannot be (re)placed: it is a file, or it holds files of something else."""


def write_outputs(out_dir: Path, result: ProcessResult, session: RawSession, session_dir: Path,
                  stationing: Stationing | None = None, project_name: str | None = None,
                  session_name: str | None = None) -> WrittenOutputs:
    """Write track.csv, fixes.csv and summary.json as the folder ``out_dir``, all or nothing.

    ``stationing`` (the design's station equations) gives track.csv its drawing chainage;
    ``project_name``, ``session_name``: see :func:`summary_dict`.

    The files are written into a new hidden folder beside ``out_dir`` and that folder is renamed
    to ``out_dir`` when all three are complete. An existing ``out_dir`` (from an earlier run)
    stays as it was until then; it is renamed aside just before and deleted just after (POSIX
    has no portable atomic exchange of two folders; if the second rename fails the first is
    undone). A failure at any point leaves either the old folder or the new one, never a mix.

    Raises
    ------
    OutputFolderError if ``out_dir`` is a file or holds anything but these three files and a field
    session's ``field_record.json`` (:data:`COMPANION_NAMES`; it is replaced as a whole, so it must
    not be, say, the session folder).
    """
    import secrets

    from survey.atomicwrite import enclosing_raw_folder

    out_dir = Path(out_dir)
    inside = enclosing_raw_folder(out_dir)
    if inside is not None:
        raise OutputFolderError(f"{out_dir}: is inside the raw session {inside} (never written into); choose a "
                                "folder outside it")
    if out_dir.exists():
        if not out_dir.is_dir():
            raise OutputFolderError(f"{out_dir}: exists and is not a folder")
        others = sorted(p.name for p in out_dir.iterdir() if p.name not in OUTPUT_NAMES + COMPANION_NAMES)
        if others:
            raise OutputFolderError(f"{out_dir}: holds {others[0]!r} (and {len(others) - 1} more), not only the "
                                    f"outputs of trolley process; give a new folder or one that trolley process "
                                    f"wrote (it is replaced as a whole)")
    parent = out_dir.absolute().parent
    parent.mkdir(parents=True, exist_ok=True)
    token = secrets.token_hex(4)
    tmp = parent / f".{out_dir.name}.partial-{token}"
    tmp.mkdir()  # plain mkdir: the folder keeps the user's umask once it is renamed to out_dir
    try:
        write_track_csv(tmp / "track.csv", result, stationing)
        fixes_frame(result).to_csv(tmp / "fixes.csv", index=False, float_format="%.6f", na_rep="")
        # jsonout: a value that does not exist (the RMS innovation of one fix) is null, never NaN
        (tmp / "summary.json").write_text(jsonout.dumps(summary_dict(
            result, session, session_dir, project_name=project_name, session_name=session_name), indent=2) + "\n",
                                          encoding="utf-8")
        move_into_place(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return WrittenOutputs(out_dir / "track.csv", out_dir / "fixes.csv", out_dir / "summary.json")


def rms_mm(x: np.ndarray) -> float:
    """RMS of finite values, in mm."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(units.m_to_mm(np.sqrt(np.mean(x**2)))) if x.size else float("nan")
