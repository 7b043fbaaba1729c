"""Writing the processed track: ``track.csv`` (FORMATS.md section 2), ``fixes.csv``, ``summary.json``.

Conversions to mm happen here, at the edge. Files are written into a temporary folder beside the
output and moved into place only when all of them are complete, so a failure never leaves a
partial output.
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from trolley import units
from trolley.engine import ProcessResult
from trolley.session import RawSession

TRACK_COLUMNS = ["chainage_m", "E_m", "N_m", "H_m", "sigma_E_mm", "sigma_N_mm", "sigma_H_mm",
                 "lateral_dev_mm", "vertical_dev_mm", "gauge_mm", "cant_mm", "twist_mm"]
FIX_COLUMNS = ["t_s", "point", "E_m", "N_m", "H_m", "innov_E_mm", "innov_N_mm", "innov_H_mm",
               "nis", "accepted", "reason"]


@dataclass(frozen=True)
class WrittenOutputs:
    """Paths of the files :func:`write_outputs` produced."""

    track_csv: Path
    fixes_csv: Path
    summary_json: Path


def track_frame(result: ProcessResult) -> pd.DataFrame:
    """The stations as the ``track.csv`` table (mm at the edge)."""
    s = result.stations
    mm = units.m_to_mm
    return pd.DataFrame({
        "chainage_m": s.chainage_m, "E_m": s.E_m, "N_m": s.N_m, "H_m": s.H_m,
        "sigma_E_mm": mm(s.sigma_E_m), "sigma_N_mm": mm(s.sigma_N_m), "sigma_H_mm": mm(s.sigma_H_m),
        "lateral_dev_mm": mm(s.lateral_dev_m), "vertical_dev_mm": mm(s.vertical_dev_m),
        "gauge_mm": mm(s.gauge_m), "cant_mm": mm(s.cant_m), "twist_mm": mm(s.twist_m),
    }, columns=TRACK_COLUMNS)


def fixes_frame(result: ProcessResult) -> pd.DataFrame:
    """Every fix with its innovation and the gate's verdict."""
    f = result.fixes
    mm = units.m_to_mm
    return pd.DataFrame({
        "t_s": f.t_s, "point": [str(p) for p in f.point],
        "E_m": f.enh_m[:, 0], "N_m": f.enh_m[:, 1], "H_m": f.enh_m[:, 2],
        "innov_E_mm": mm(f.innovation_enh_m[:, 0]), "innov_N_mm": mm(f.innovation_enh_m[:, 1]),
        "innov_H_mm": mm(f.innovation_enh_m[:, 2]), "nis": f.nis,
        "accepted": f.accepted.astype(int), "reason": f.reason,
    }, columns=FIX_COLUMNS)


def summary_dict(result: ProcessResult, session: RawSession, session_dir: Path) -> dict:
    """The run summary that the export and the terminal show."""
    imu = session.meta.imu
    s = result.summary
    return {
        "session_dir": str(Path(session_dir).resolve()),
        "project": Path(session_dir).resolve().parent.name,
        "session": Path(session_dir).resolve().name,
        "imu": {
            "name": imu.name,
            "gyro_bias_instability_deg_h": float(units.rad_s_to_deg_h(imu.gyro_bias_instability_rad_s)),
            "gyro_arw_deg_sqrt_h": float(units.rad_sqrt_s_to_deg_sqrt_h(imu.gyro_arw_rad_sqrt_s)),
        },
        "smoother": result.config.smoother,
        "fixes_used": s["fixes_used"],
        "fixes_rejected": s["fixes_rejected"],
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
    }


def write_outputs(out_dir: Path, result: ProcessResult, session: RawSession, session_dir: Path) -> WrittenOutputs:
    """Write track.csv, fixes.csv and summary.json into ``out_dir``, all or nothing."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".partial-", dir=out_dir))
    try:
        track_frame(result).to_csv(tmp / "track.csv", index=False, float_format="%.6f", na_rep="")
        fixes_frame(result).to_csv(tmp / "fixes.csv", index=False, float_format="%.6f", na_rep="")
        (tmp / "summary.json").write_text(json.dumps(summary_dict(result, session, session_dir), indent=2) + "\n",
                                          encoding="utf-8")
        for name in ("track.csv", "fixes.csv", "summary.json"):
            os.replace(tmp / name, out_dir / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return WrittenOutputs(out_dir / "track.csv", out_dir / "fixes.csv", out_dir / "summary.json")


def rms_mm(x: np.ndarray) -> float:
    """RMS of finite values, in mm."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(units.m_to_mm(np.sqrt(np.mean(x**2)))) if x.size else float("nan")
