"""Export a processed track: geometry parameters, tolerance check, workbook, CSV and plots.

``export_outputs`` is the one entry point (the ``trolley export`` command and ``trolley demo``
call it). It reads track.csv (and, beside it, fixes.csv, summary.json and the field session's
field_record.json when present; the
design LandXML named by the session's session.toml), computes every parameter
(:mod:`trolley.trackgeometry`), checks them against a tolerance set
(:mod:`trolley.tolerances`) and writes the requested outputs, each atomically.
"""
from __future__ import annotations

import csv
import functools
import io
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from trolley.tolerances import ToleranceSet, find_defects
from trolley.trackgeometry import (ABSOLUTE_COLUMNS, FIX_NEAR_TRACK_M, GAP_STEPS, GeometryConfig, column_stats,
                                  fixed_span, track_geometry)

from survey.atomicwrite import all_or_nothing, check_outputs, check_suffix, write_text_atomic
from survey.fieldrecord import FIELD_RECORD, read_field_record
from survey.limits import check_file_option
from survey.sheet_text import csv_safe_text
from survey.tolerance_files import load_tolerances
from survey.track_reader import (ExportInputError, add_design, design_alignment_name, design_alignment_path,
                                 read_fixes_csv, read_summary_json, read_track_file, resolve_track_csv, session_equipment,
                                 SurveyInfo)
from survey.track_table import SurveyReport, column_values, fix_chainages, sheet_columns

DEFAULT_TOLERANCES = "hsr_ballastless_static"


@dataclass
class ExportResult:
    """What an export produced.

    Attributes
    ----------
    report : the survey report (geometry, defects, statistics).
    xlsx, pdf, csv, plots : files written (None / empty when not requested).
    timings_s : seconds per stage ("read", "geometry", "check", "xlsx", "csv", "plots").
    """

    report: SurveyReport
    xlsx: Path | None = None
    pdf: Path | None = None
    csv: Path | None = None
    plots: list[Path] = field(default_factory=list)
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def defects(self) -> int:
        return len(self.report.defects)

    @property
    def passed(self) -> bool:
        return self.report.passed

    def as_dict(self) -> dict:
        """JSON-ready summary (for the CLI's stdout)."""
        rep = self.report
        return {
            "track_csv": str(rep.track_csv), "stations": int(rep.geometry.chainage_m.size),
            "step_m": rep.geometry.step_m, "tolerances": rep.tolerances.name,
            "design": str(rep.design_file) if rep.design_file else None,
            "defects": len(rep.defects), "passed": rep.passed,
            "xlsx": str(self.xlsx) if self.xlsx else None, "pdf": str(self.pdf) if self.pdf else None, "csv": str(self.csv) if self.csv else None,
            "plots": [str(p) for p in self.plots], "notes": rep.notes,
            "timings_s": {k: round(v, 4) for k, v in self.timings_s.items()},
        }


def geometry_config(tol: ToleranceSet, info: SurveyInfo, **overrides) -> GeometryConfig:
    """Geometry settings: defaults, then the tolerance set's [geometry], then the survey's
    rail spacing / nominal gauge, then explicit ``overrides`` (None values ignored)."""
    cfg = GeometryConfig(rail_spacing_m=info.rail_spacing_m, nominal_gauge_m=info.nominal_gauge_m)
    from_tol = {k: getattr(tol, k) for k in ("twist_base_m", "gauge_rate_base_m", "versine_chord_m")
                if getattr(tol, k) is not None}
    cfg = replace(cfg, **from_tol)
    return replace(cfg, **{k: v for k, v in overrides.items() if v is not None})


#: The option that sets each geometry base (the tolerance set's key has the field's name).
_BASE_OPTIONS = {"twist_base_m": "--twist-base-m", "versine_chord_m": "--chord-m", "gauge_rate_base_m": "--gauge-rate-base-m"}


def _check_bases(cfg: GeometryConfig, chainage_m: np.ndarray, path: Path) -> None:
    """Every base and chord must be finite and at least one station step long: a shorter one
    cannot be evaluated from the stations of ``path``.

    Raises
    ------
    ExportInputError naming the option (and the tolerance-set key).
    """
    step = float(np.median(np.diff(chainage_m))) if chainage_m.size > 1 else 0.0
    for name, option in _BASE_OPTIONS.items():
        v = float(getattr(cfg, name))
        if not np.isfinite(v) or v < step:
            raise ExportInputError(f"{option} ({name}) {v:g} m: must be finite and at least the station step "
                                   f"{step:g} m of {path}")


def survey_info(folder: Path, project_name: str | None = None, session_name: str | None = None) -> SurveyInfo:
    """What the Summary sheet says about the survey whose track.csv lies in ``folder``.

    summary.json beside track.csv, if present; equipment figures it lacks (older files) from
    its session's session.toml; then the explicit names, which win over summary.json's.
    """
    info = read_summary_json(folder / "summary.json") if (folder / "summary.json").is_file() else SurveyInfo()
    if not info.equipment and info.session_dir:
        info.equipment, note = session_equipment(Path(info.session_dir))
        info.equipment_source = str(Path(info.session_dir) / "session.toml") if info.equipment else note
    if project_name:
        info.project = project_name
    if session_name:
        info.session = session_name
    return info


def build_report(track_csv: Path, tolerances: str = DEFAULT_TOLERANCES, design: Path | None = None,
                 project_name: str | None = None, session_name: str | None = None,
                 design_name: str | None = None, **config_overrides) -> tuple[SurveyReport, dict[str, float]]:
    """Read the inputs, compute the geometry and the defects.

    Parameters
    ----------
    track_csv : track.csv or a folder holding it (see :func:`survey.track_reader.resolve_track_csv`).
    tolerances : built-in tolerance set name or a TOML file path.
    design : LandXML file overriding the one the session names (optional).
    project_name, session_name : names for the Summary sheet (override summary.json's).
    design_name : the alignment to read from a LandXML file holding several (default: the
        session's [design] name).
    config_overrides : GeometryConfig fields (twist_base_m, versine_chord_m, cant_sign, ...).

    Returns
    -------
    report, timings_s
    """
    t0 = time.perf_counter()
    path = resolve_track_csv(Path(track_csv))
    folder = path.parent
    file = read_track_file(path)
    track = file.track
    notes: list[str] = list(file.notes)
    info = survey_info(folder, project_name, session_name)
    fixes = read_fixes_csv(folder / "fixes.csv") if (folder / "fixes.csv").is_file() else None
    record = read_field_record(folder / FIELD_RECORD) if (folder / FIELD_RECORD).is_file() else None
    if record is not None:   # the field session's names, unless given explicitly
        info.project = project_name or record.project or info.project
        info.session = session_name or record.session or info.session
    tol = load_tolerances(tolerances)
    cfg = geometry_config(tol, info, **config_overrides)
    _check_bases(cfg, track.chainage_m, path)
    design_file = Path(design) if design else design_alignment_path(info)
    stationing = file.stationing     # the design's (exact) replaces it below when it has equations
    if design_file is not None:
        if not design_file.is_file():
            raise ExportInputError(f"{design_file}: design alignment file not found")
        track, design_stationing = add_design(track, design_file, cfg.rail_spacing_m,
                                              design_name or design_alignment_name(info),
                                              notes)
        stationing = design_stationing or stationing
    else:
        notes.append("no design alignment (summary.json / session.toml [design]): design columns empty")
        if stationing is not None:
            notes.append("track.csv chainage_m jumps against distance_m: the chainages shown are track.csv's "
                         "chainage_m, each station equation placed at the first station after its jump")
    if np.isnan(track.lateral_dev_m).all():
        notes.append("track.csv has no lateral/vertical deviations: alignment, level, long-chord and "
                     "band values are empty")
    for name, values in (("gauge_mm", track.gauge_m), ("cant_mm", track.cant_m)):
        if np.isnan(values).all():
            notes.append(f"track.csv has no {name}: its tolerances are not checked")
    t1 = time.perf_counter()
    geometry = track_geometry(track, cfg)
    if geometry.gaps_m:
        spans = ", ".join(f"{shown_station(stationing, a):.3f}-{shown_station(stationing, b):.3f} m"
                          for a, b in geometry.gaps_m)
        notes.append(f"track.csv has no stations in {spans} (longer than {GAP_STEPS:g} steps of "
                     f"{geometry.step_m:g} m): the stations there are empty, not interpolated")
    absolute_checked = absolute_span(geometry, fixes, notes, stationing)
    t2 = time.perf_counter()
    columns = sheet_columns(cfg)
    # checked and summarised as the files keep them (rounded to the digits written), so the
    # sheet's peak, its red cells and the verdict agree at a limit
    kept = {c.key: c.kept(geometry.columns[c.key]) for c in columns if c.key in geometry.columns}
    checked = {k: kept.get(k, v) for k, v in geometry.columns.items()}
    if absolute_checked is not None:
        for k in ABSOLUTE_COLUMNS:
            if k in checked:
                checked[k] = np.where(absolute_checked, checked[k], np.nan)
    defects = find_defects(geometry.chainage_m, checked, tol)
    stats = {k: column_stats(k, v) for k, v in checked.items()}
    t3 = time.perf_counter()
    rep = SurveyReport(track_csv=path, geometry=geometry, columns=columns, tolerances=tol,
                       defects=defects, stats=stats, info=info, fixes=fixes, design_file=design_file,
                       notes=notes, record=record, stationing=stationing,
                       cov_EN=file.track.cov_EN_m2 is not None, absolute_checked=absolute_checked)
    return rep, {"read": t1 - t0, "geometry": t2 - t1, "check": t3 - t2}


#: the start of the Summary note on stations outside the outermost fixes
UNFIXED_NOTE = "deviations from the design not checked"
#: the notes that say what was not checked, which a PASS must not hide: ``trolley export`` prints
#: them before its verdict, the PDF's summary page lists them (:func:`unchecked_notes`)
UNCHECKED_NOTES = ("track.csv column", "track.csv has no gauge_mm", "track.csv has no stations", UNFIXED_NOTE)


def unchecked_notes(rep: SurveyReport) -> list[str]:
    """The report's notes that say what was not checked (:data:`UNCHECKED_NOTES`)."""
    return [n for n in rep.notes if n.startswith(UNCHECKED_NOTES)]


def shown_station(stationing, internal_m: float) -> float:
    """The drawing station of an internal one in the notes (itself without station equations)."""
    return float(internal_m) if stationing is None else float(stationing.station(internal_m))


def absolute_span(geometry, fixes, notes: list[str], stationing=None) -> np.ndarray | None:
    """Per station, whether its absolute parameters (deviations from the design, slew, lift) are
    checked against the tolerances: between the first and the last fix the processing used
    (:func:`trolley.trackgeometry.fixed_span`). None: every station (no fixes.csv, or no used fix
    on the surveyed track; said in ``notes``).

    Beyond the outermost fixes a station's position is dead reckoning from one fix: a session
    ended 1140 m after its last fix had sigmas up to 495 mm there and 38 "defects" that were the
    drift (bug hunt 2026-11-27). Its relative parameters (gauge, cant, twist, versines, chords,
    bands) rest on the trolley's own sensors over a short base and are still checked; the
    stations outside are said in ``notes`` with their largest sigma.
    """
    if fixes is None:
        return None
    acc, _ = fix_chainages(geometry, fixes)
    if not acc.size:
        if any(f.accepted for f in fixes):
            notes.append(f"no fix of fixes.csv that the processing used lies on the surveyed track (within "
                         f"{FIX_NEAR_TRACK_M:g} m): the deviations from the design are checked at every station")
        return None
    inside = fixed_span(geometry.chainage_m, acc)
    s = geometry.chainage_m
    outside = ~inside & np.isfinite(geometry.columns["lateral_dev_m"] + geometry.columns["vertical_dev_m"])
    if not outside.any():
        return None
    shown = functools.partial(shown_station, stationing)
    parts = []
    for side, sel, fix in (("before the first", outside & (s < acc.min()), acc.min()),
                           ("beyond the last", outside & (s > acc.max()), acc.max())):
        if sel.any():
            lat = column_stats("", geometry.columns["sigma_lateral_m"][sel]).maximum
            ver = column_stats("", geometry.columns["sigma_vertical_m"][sel]).maximum
            parts.append(f"{shown(s[sel][0]):.3f}-{shown(s[sel][-1]):.3f} m, {side} fix used ({shown(fix):.3f} m; "
                         f"sigma lateral up to {1e3 * lat:.1f} mm, vertical up to {1e3 * ver:.1f} mm)")
    notes.append(f"{UNFIXED_NOTE} at stations " + " and ".join(parts) + ": their position is dead reckoning from "
                 "one fix; their lateral and vertical deviations, slew and lift are shown, not checked against the "
                 "tolerances; their gauge, cant, twist, versines, chords and bands are checked")
    return inside


def write_track_csv(path: Path, rep: SurveyReport) -> Path:
    """The Track table as CSV (display units in the column names), injection-safe, atomic.

    ``chainage_m`` is the drawing stationing (:meth:`SurveyReport.station`); the last column
    ``distance_m`` is the internal station (equal to chainage_m without station equations).

    Numbers are plain numbers (empty when not available); the only text is the header, which
    passes through :func:`survey.sheet_text.csv_safe_text` like any text would.
    """
    path = Path(path)
    cols = [c for c in rep.columns if c.key != "station_km"]
    station = rep.station_m
    data = [column_values(c, rep.geometry, station) for c in cols]
    # chainage_m is the drawing stationing; the last column distance_m the internal station it
    # jumps against at station equations (as in track.csv, docs/conventions.md)
    body = np.column_stack(data + [np.round(rep.geometry.chainage_m, 6)])
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([csv_safe_text(c.csv_name) for c in cols] + [csv_safe_text("distance_m")])
    # repr of the rounded floats, NaN -> empty. Measured on 16 000 x 44 values: this comprehension
    # (0.17 s) is as fast as formatting per column and faster than numpy's astype(str) (0.28 s)
    # or pandas.to_csv (0.28 s), which give the same text.
    lines = [",".join("" if v - v != 0 else repr(v) for v in row) for row in body.tolist()]  # NaN, +-inf: empty
    return write_text_atomic(path, buf.getvalue() + "\n".join(lines) + "\n")


def export_outputs(track_csv: Path, xlsx: Path | None, csv: Path | None, plots_dir: Path | None,
                   tolerances: str = DEFAULT_TOLERANCES, design: Path | None = None,
                   project_name: str | None = None, session_name: str | None = None,
                   progress: Callable[[str, float], None] | None = None, pdf: Path | None = None,
                   design_name: str | None = None, **config_overrides) -> ExportResult:
    """Compute the survey sheet of a processed track and write the requested outputs.

    Parameters
    ----------
    track_csv : track.csv, a processing output folder holding track.csv, or a field-session /
        demo output folder holding processed/track.csv (fixes.csv and summary.json beside
        track.csv are used when present).
    xlsx, csv : files to write (None: skip).
    plots_dir : folder for PNG plots (None: skip).
    tolerances : built-in set name (``hsr_ballastless_static``, ``en13848_5_alert``) or a TOML
        file path.
    design : LandXML alignment to use instead of the one named by the session.
    design_name : the alignment to read from a LandXML file holding several (default: the
        session's [design] name).
    project_name, session_name : project and session names for the Summary sheet and the plot
        titles; they override summary.json's (which knows only what ``trolley process`` was
        told). The field session passes its project store's and session's names.
    progress : optional ``progress(step, fraction)`` called before each stage (geometry, workbook,
        CSV, plots, PDF) with the fraction of the export done (survey/commands/progress.py).
    pdf : PDF report to write (survey/reportpdf.py; None: skip).
    config_overrides : :class:`trolley.trackgeometry.GeometryConfig` fields.

    Returns
    -------
    ExportResult (``plots`` lists the PNG files written)

    Raises
    ------
    ExportInputError, trolley.tolerances.ToleranceError
        Unusable input (the message names file, row and column).
    """
    check_export_outputs(track_csv, xlsx, csv, plots_dir, tolerances, design, pdf)
    # rough shares of the run time of each stage, for the progress bar only
    shares = {"geometry": 0.3, "xlsx": 0.4 if xlsx is not None else 0.0, "csv": 0.05 if csv is not None else 0.0,
              "plots": 0.25 if plots_dir is not None else 0.0, "pdf": 0.4 if pdf is not None else 0.0}
    total = sum(shares.values())
    done = 0.0

    def report(step: str, stage: str) -> None:
        nonlocal done
        if progress is not None:
            progress(step, done / total)
        done += shares[stage]

    report("computing the track geometry", "geometry")
    rep, timings = build_report(track_csv, tolerances, design, project_name, session_name, design_name,
                                **config_overrides)
    result = ExportResult(report=rep, timings_s=timings)
    with all_or_nothing():  # every output complete, then all renamed into place; or none
        if xlsx is not None:
            from survey.workbook import write_workbook

            report("writing the survey sheet", "xlsx")
            t = time.perf_counter()
            stages: dict[str, float] = {}
            result.xlsx = write_workbook(Path(xlsx), rep, stages)
            timings["xlsx"] = time.perf_counter() - t
            timings.update({f"xlsx_{k}": v for k, v in stages.items()})
        if csv is not None:
            report("writing the track CSV", "csv")
            t = time.perf_counter()
            result.csv = write_track_csv(Path(csv), rep)
            timings["csv"] = time.perf_counter() - t
        if plots_dir is not None:
            from survey.plots import write_plots

            report("drawing the plots", "plots")
            t = time.perf_counter()
            result.plots = write_plots(Path(plots_dir), rep)
            timings["plots"] = time.perf_counter() - t
        if pdf is not None:
            from survey.reportpdf import write_pdf_report

            report("writing the PDF report", "pdf")
            t = time.perf_counter()
            result.pdf = write_pdf_report(Path(pdf), rep).path
            timings["pdf"] = time.perf_counter() - t
    return result


def _made_by_export(path: Path) -> bool:
    """True for a CSV that :func:`write_track_csv` wrote (its header has the design columns)."""
    try:
        with open(path, encoding="utf-8") as fh:
            return fh.readline().startswith(_EXPORT_CSV_HEAD)
    except (OSError, UnicodeDecodeError):
        return False


_EXPORT_CSV_HEAD = "chainage_m,E_m,N_m,H_m,sigma_E_mm,sigma_N_mm,sigma_H_mm,design_E_m,"


def check_export_outputs(track_csv: Path, xlsx: Path | None, csv: Path | None, plots_dir: Path | None,
                         tolerances: str = DEFAULT_TOLERANCES, design: Path | None = None,
                         pdf: Path | None = None) -> None:
    """Check every output before any is written: folders exist and are writable, no output is one
    of the inputs (track.csv, fixes.csv, summary.json, design, tolerance file) or a raw session
    file, no two options name the same file, each file's name ends in its format's suffix (.xlsx,
    .pdf, .csv).

    Raises
    ------
    survey.atomicwrite.OutputError, ExportInputError
    """
    # the names first, before the track is even looked for: a workbook named x.csv is no output
    for option, value, suffix, what in (("--xlsx", xlsx, ".xlsx", "an Excel workbook"),
                                        ("--pdf", pdf, ".pdf", "a PDF report"), ("--csv", csv, ".csv", "a CSV table")):
        check_suffix(option, value, suffix, what)
    # "design alignment file not found" named no option
    check_file_option(design, "--design", "a LandXML design file", "alignment.xml")
    path = resolve_track_csv(Path(track_csv))
    inputs = [path, path.parent / "fixes.csv", path.parent / "summary.json", design,
              Path(tolerances) if Path(tolerances).suffix.lower() == ".toml" else None]
    check_outputs([("--xlsx", xlsx), ("--csv", csv), ("--pdf", pdf)], inputs=inputs, folders=[("--plots", plots_dir)],
                  made_before=_made_by_export)
