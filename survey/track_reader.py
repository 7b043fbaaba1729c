"""Reading the processing outputs the export needs: track.csv, fixes.csv, summary.json, design.

``track.csv`` follows FORMATS.md section 2; ``fixes.csv`` and ``summary.json`` are the engine's
(survey/trackio.py). Bad input is a :class:`ExportInputError` whose message names the file, the
row (data row + 1, i.e. the row number a spreadsheet shows; blank lines are not counted) and
the column.

Missing values: in track.csv the columns lateral_dev_mm, vertical_dev_mm, gauge_mm, cant_mm and
twist_mm may be empty (no design / not measured); an empty cell or the text ``nan`` there is
"not available". Every other cell must be a finite number; chainage (distance_m when present) must increase
strictly.
"""
from __future__ import annotations

import csv
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trolley import units
from trolley.numbertext import all_plain, parse_number
from trolley.stationing import StationEquation, Stationing
from trolley.trackgeometry import TrackInput

from survey.names import inside
from survey.sessionio import PLAUSIBLE_ABS, line_spans
from survey.sheet_text import csv_read_text

TRACK_REQUIRED = ["chainage_m", "E_m", "N_m", "H_m", "sigma_E_mm", "sigma_N_mm", "sigma_H_mm"]
TRACK_OPTIONAL = ["lateral_dev_mm", "vertical_dev_mm", "gauge_mm", "cant_mm", "twist_mm", "distance_m",
                  "cov_EN_mm2", "sigma_cant_mm"]
FIX_NUMERIC = ["t_s", "E_m", "N_m", "H_m", "innov_E_mm", "innov_N_mm", "innov_H_mm", "nis"]


class ExportInputError(ValueError):
    """An input file the export cannot use (message: file, row, column)."""


@dataclass
class FixRow:
    """One prism fix of the engine's fixes.csv (SI; innovations in m)."""

    t_s: float
    point: str
    E_m: float
    N_m: float
    H_m: float
    innov_E_m: float
    innov_N_m: float
    innov_H_m: float
    nis: float
    accepted: bool
    reason: str


#: equipment figures of session.toml in display units: key -> (Summary label, number format)
EQUIPMENT = {
    "gyro_bias_instability_deg_h": ("Gyro bias instability [deg/h]", "0.0000"),
    "gyro_arw_deg_sqrt_h": ("Gyro ARW [deg/sqrt(h)]", "0.0000"),
    "accel_bias_ug": ("Accelerometer bias [µg]", "0.0"),
    "odometer_scale_noise_per_sqrt_s": ("Odometer scale noise [1/sqrt(s)]", "0.0E+00"),
    "totalstation_sigma_mm": ("Total-station sigma [mm]", "0.00"),
    "prism_lever_arm_m": ("Prism lever arm x, y, z (FRD) [m]", "0.000"),
    "rail_spacing_m": ("Rail spacing [m]", "0.000"),
    "nominal_gauge_mm": ("Nominal gauge [mm]", "0.0"),
}


def equipment_figures(meta) -> dict:
    """The equipment figures of a session's metadata in display units (keys of :data:`EQUIPMENT`).

    Parameters
    ----------
    meta : trolley.session.SessionMeta (session.toml, SI).

    Returns
    -------
    dict, JSON-ready (summary.json ``equipment``); the IMU figures are absent when
    session.toml has no [imu] table.
    """
    def back(x) -> float:
        # session.toml -> SI -> display units again: 15 digits give 0.005, not 0.005000000000000001
        return float(f"{float(x):.15g}")

    tr = meta.trolley
    out: dict = {}
    if meta.imu is not None:
        imu = meta.imu
        out.update(imu_name=str(imu.name),
                   gyro_bias_instability_deg_h=back(units.rad_s_to_deg_h(imu.gyro_bias_instability_rad_s)),
                   gyro_arw_deg_sqrt_h=back(units.rad_sqrt_s_to_deg_sqrt_h(imu.gyro_arw_rad_sqrt_s)),
                   accel_bias_ug=back(units.m_s2_to_ug(imu.accel_bias_m_s2)))
    out.update(odometer_scale_noise_per_sqrt_s=float(meta.odometer.scale_noise_per_sqrt_s),
               totalstation_sigma_mm=back(units.m_to_mm(meta.fix_sigma_m)),
               prism_lever_arm_m=[float(x) for x in np.asarray(tr.prism_lever_arm_m, dtype=float)],
               rail_spacing_m=float(tr.rail_spacing_m), nominal_gauge_mm=back(units.m_to_mm(tr.nominal_gauge_m)))
    return out


@dataclass
class SurveyInfo:
    """What the Summary sheet shows about the survey (from summary.json; defaults if absent).

    ``equipment`` holds the figures of :data:`EQUIPMENT` that are known (summary.json
    ``equipment``, else the session's session.toml); ``equipment_source`` says where from.
    ``crs``, ``vertical_datum``: the project grid ("" = not given: a local grid, true north);
    ``grid_scale_factor`` (the projection's point scale k), ``grid_combined_scale`` (k times the
    height reduction) and ``grid_convergence_deg`` at the site (NaN without a CRS;
    ``trolley.projection``).
    """

    project: str = ""
    session: str = ""
    session_dir: str = ""
    imu_name: str = ""
    gyro_bias_instability_deg_h: float = math.nan
    gyro_arw_deg_sqrt_h: float = math.nan
    equipment: dict = field(default_factory=dict)
    equipment_source: str = ""
    smoother: str = ""
    fixes_used: int | None = None
    fixes_rejected: int | None = None
    rms_innovation_mm: float = math.nan
    max_sigma_mm: float = math.nan
    step_m: float = math.nan
    rail_spacing_m: float = 1.500
    nominal_gauge_m: float = 1.435
    present: bool = False
    crs: str = ""
    vertical_datum: str = ""
    grid_scale_factor: float = math.nan
    grid_convergence_deg: float = math.nan
    grid_combined_scale: float = math.nan
    extra: dict = field(default_factory=dict)


def resolve_track_csv(path: Path) -> Path:
    """The track.csv to export, from a file or a folder.

    Accepted: a track.csv file; a processing output folder holding ``track.csv``
    (``trolley process SESSION --out OUT``); a field-session or demo output folder holding
    ``processed/track.csv`` (survey/session/final.py). A raw session folder (session.toml and
    imu.csv, FORMATS.md section 1) has no track yet: the error says to process it first.
    """
    path = Path(path)
    if path.is_dir():
        for cand in (path / "track.csv", path / "processed" / "track.csv"):
            if cand.is_file():
                return cand
        if (path / "session.toml").is_file() and (path / "imu.csv").is_file():
            raise ExportInputError(
                f"{path}: a raw session folder (session.toml, imu.csv), not yet processed: run "
                f"`trolley process {path} --out OUT` first, then `trolley export OUT --xlsx FILE`")
        raise ExportInputError(f"{path}: folder has no track.csv (nor processed/track.csv)")
    if not path.is_file():
        raise ExportInputError(f"{path}: no such file or folder")
    return path


def _parse_float(text: str, where: str, allow_missing: bool) -> float:
    t = text.strip()
    if t == "" or t.lower() == "nan":
        if allow_missing:
            return math.nan
        raise ExportInputError(f"{where}: value missing")
    try:
        v = parse_number(t)
    except ValueError as exc:
        raise ExportInputError(f"{where}: {exc}") from None
    if not math.isfinite(v):
        raise ExportInputError(f"{where}: not finite: {t[:40]!r}")
    return v


def _read_csv_rows(path: Path) -> tuple[list[str], list[list[str]]]:
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except UnicodeDecodeError as e:
        raise ExportInputError(f"{path}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    except csv.Error as e:
        raise ExportInputError(f"{path}: not a CSV file ({e})") from None
    if not rows:
        raise ExportInputError(f"{path}: empty file (no header row)")
    header = [h.strip() for h in rows[0]]
    for i, r in enumerate(rows[1:], start=2):
        if len(r) > len(header) and any(c.strip() for c in r[len(header):]):
            # more cells than columns: a decimal comma ("0,5") splits a number in two, and the
            # cells after it would be read into the wrong columns (trolley process refuses it too)
            raise ExportInputError(f"{path}: row {i}: {len(r)} cells, the header has {len(header)} columns "
                                   "(a decimal comma? use a point: 0.5)")
        if len(r) < len(header) and any(c.strip() for c in r):
            # fewer: a row cut short (a file copied while it was written, a lost separator); its
            # missing cells would silently read as "not measured"
            raise ExportInputError(f"{path}: row {i}: {len(r)} cells, the header has {len(header)} columns "
                                   "(a truncated row?)")
    body = [r for r in rows[1:] if any(c.strip() for c in r)]
    return header, body


def _numeric_columns(path: Path, header: list[str], body: list[list[str]], names: list[str],
                     optional: set[str]) -> dict[str, np.ndarray]:
    col = {h: i for i, h in enumerate(header)}
    missing = [n for n in names if n not in col]
    if missing:
        raise ExportInputError(f"{path}: missing column(s) {', '.join(missing)} (header: {','.join(header)})")
    out = {}
    for name in names:
        j = col[name]
        raw = [r[j] if j < len(r) else "" for r in body]
        try:
            # fast path: numpy parses the whole column; on any problem find the bad row
            arr = np.array([x if x.strip() else "nan" for x in raw], dtype=float)
            bad = ~np.isfinite(arr)
            if name in optional:
                bad &= ~np.isnan(arr)
            if bad.any() or not all_plain(raw):
                raise ValueError
        except ValueError:
            for i, x in enumerate(raw):
                _parse_float(x, f"{path}: row {i + 2}, column {name}", name in optional)
            raise ExportInputError(f"{path}: column {name}: unreadable values") from None
        out[name] = arr
    return out


def _same_cell_count_on_every_line(path: Path) -> bool:
    """True when every non-blank line of an unquoted CSV has the header's number of commas
    (counted vectorised over the bytes; a file with quotes or unreadable gives False)."""
    try:
        data = np.frombuffer(path.read_bytes(), np.uint8)
    except OSError:
        return False
    if (data == ord('"')).any():
        return False
    starts, ends, used = line_spans(data)
    commas = np.r_[0, np.cumsum(data == ord(","))]
    per_line = commas[ends] - commas[starts]
    return bool(used.any()) and bool(np.all(per_line[used] == per_line[used][0]))


def _track_columns_fast(path: Path) -> dict[str, np.ndarray] | None:
    """The track.csv columns parsed by pandas' C reader, or None when anything is unusual.

    Only a clean file is accepted here (every required value finite, optional values finite or
    empty); anything else (text, inf, ``nan`` text, blank cells, odd header) returns None and
    :func:`_numeric_columns` reads the file again cell by cell to name the bad row, so the
    result and the messages are those of the strict reader.
    """
    import pandas as pd

    if not _same_cell_count_on_every_line(path):
        return None          # pandas would fill a short row with NaN: the strict reader names it
    try:
        df = pd.read_csv(path, encoding="utf-8-sig", keep_default_na=False, na_values=[""], engine="c")
    except (ValueError, UnicodeDecodeError, pd.errors.ParserError, pd.errors.EmptyDataError):
        return None
    names = list(df.columns)
    if len(set(names)) != len(names) or any(not isinstance(h, str) or h != h.strip() for h in names):
        return None
    if any(n not in names for n in TRACK_REQUIRED) or df.shape[0] == 0:
        return None
    out = {}
    for name in TRACK_REQUIRED + [n for n in TRACK_OPTIONAL if n in names]:
        if df[name].dtype.kind not in "fi":
            return None
        arr = np.array(df[name], dtype=float)       # a writable copy (pandas 3 arrays are read-only)
        ok = np.isfinite(arr) if name in TRACK_REQUIRED else ~np.isinf(arr)
        if not ok.all():
            return None
        out[name] = arr
    return out


#: Largest plausible |value| of track.csv's mm columns (the SI ones: sessionio.PLAUSIBLE_ABS):
#: a 1-sigma or deviation beyond 100 m, a gauge, cant or twist beyond 10 m is a corrupt cell.
_TRACK_PLAUSIBLE_ABS_MM = {"sigma_E_mm": 1e5, "sigma_N_mm": 1e5, "sigma_H_mm": 1e5, "lateral_dev_mm": 1e5,
                           "vertical_dev_mm": 1e5, "gauge_mm": 1e4, "cant_mm": 1e4, "twist_mm": 1e4,
                           "cov_EN_mm2": 1e10, "sigma_cant_mm": 1e4}


def _check_plausible_track(path: Path, cols: dict[str, np.ndarray]) -> None:
    """Refuse finite but absurd values (1e308 in H_m): they would reach the sheet as inf."""
    for name, v in cols.items():
        limit = PLAUSIBLE_ABS.get(name, _TRACK_PLAUSIBLE_ABS_MM.get(name, math.inf))
        with np.errstate(invalid="ignore"):
            far = np.abs(v) > limit
        if far.any():
            i = int(np.argmax(far))
            raise ExportInputError(f"{path}: row {i + 2}, column {name}: {float(v[i]):g} is not a plausible value "
                                   f"(|{name}| <= {limit:g})")
    for name in ("sigma_E_mm", "sigma_N_mm", "sigma_H_mm", "sigma_cant_mm"):
        v = cols.get(name)
        if v is not None and np.any(v < 0):       # NaN (an empty optional cell) compares False
            i = int(np.argmax(v < 0))
            raise ExportInputError(f"{path}: row {i + 2}, column {name}: {float(v[i]):g} is negative; a 1-sigma is "
                                   ">= 0")
    if "cov_EN_mm2" in cols:
        # |cov| <= sigma_E sigma_N, to the rounding of the six decimals the three are written with
        sE, sN, cov = cols["sigma_E_mm"], cols["sigma_N_mm"], cols["cov_EN_mm2"]
        with np.errstate(invalid="ignore"):
            bad = np.abs(cov) > sE * sN + 1e-6 * (1.0 + sE + sN)
        if bad.any():
            i = int(np.argmax(bad))
            with np.errstate(divide="ignore", invalid="ignore"):
                rho = cov[i] / (sE[i] * sN[i])
            raise ExportInputError(f"{path}: row {i + 2}, column cov_EN_mm2: {float(cov[i]):g} with sigma_E_mm "
                                   f"{float(sE[i]):g} and sigma_N_mm {float(sN[i]):g} is no covariance (correlation "
                                   f"{float(rho):+.3f}, must be within +-1)")


def stationing_of_track(distance_m: np.ndarray, chainage_m: np.ndarray, tol_m: float = 1e-5) -> Stationing | None:
    """The drawing stationing a track.csv shows: its ``chainage_m`` against ``distance_m``.

    Between stations the chainage runs with the distance (or against it); where it does not, a
    station equation is taken at the first station after the break, its drawing station ahead
    that station's chainage. Used when no design gives the equations exactly (a track.csv
    exported without its LandXML); the equations are then placed within one station step.

    Returns
    -------
    Stationing, or None when the chainage is the distance at every station.
    """
    d, c = np.asarray(distance_m, dtype=float), np.asarray(chainage_m, dtype=float)
    dd, dc = np.diff(d), np.diff(c)
    sign = np.where(np.abs(dc - dd) <= tol_m, 1, np.where(np.abs(dc + dd) <= tol_m, -1, 0))
    eqs: list[StationEquation] = []
    cur = 1
    if d.size and (abs(c[0] - d[0]) > tol_m or (sign.size and sign[0] == -1)):
        cur = -1 if sign.size and sign[0] == -1 else 1
        eqs.append(StationEquation(float(d[0]), float(c[0]), None, cur > 0))
    # only the steps that break the stationing or turn its direction (a handful): a short loop
    for i in np.flatnonzero((sign == 0) | (sign != np.r_[sign[:1], sign[:-1]])).tolist():
        if sign[i] == 0:
            cur = int(sign[i + 1]) if i + 1 < sign.size and sign[i + 1] != 0 else 1
            eqs.append(StationEquation(float(d[i + 1]), float(c[i + 1]), float(c[i]), cur > 0))
        elif sign[i] != cur and not (eqs and eqs[-1].internal_m == d[i]):
            cur = int(sign[i])
            eqs.append(StationEquation(float(d[i]), float(c[i]), float(c[i]), cur > 0))
    if not eqs:
        return None
    return Stationing(float(d[0]), float(d[-1] + (dd[-1] if dd.size else 1.0)), eqs)


@dataclass
class TrackFile:
    """A track.csv as the export reads it.

    Attributes
    ----------
    track : TrackInput in SI along the internal station (no design columns yet).
    twist_file_m : the file's own twist column, m (NaN where empty).
    stationing : the file's drawing stationing (:func:`stationing_of_track`), None when its
        chainage_m is its distance_m (or it has no distance_m).
    """

    track: TrackInput
    twist_file_m: np.ndarray
    stationing: Stationing | None = None
    #: what the reader noticed and ignored (a misspelled optional column), for the report
    notes: list[str] = field(default_factory=list)


def read_track_csv(path: Path) -> tuple[TrackInput, np.ndarray]:
    """Read a track.csv (FORMATS.md section 2): (track, twist_file_m) of :func:`read_track_file`."""
    f = read_track_file(path)
    return f.track, f.twist_file_m


def read_track_file(path: Path) -> TrackFile:
    """Read a track.csv (FORMATS.md section 2; distance_m, docs/conventions.md)."""
    cols = _track_columns_fast(path)
    if cols is None:
        header, body = _read_csv_rows(path)
        if not body:
            raise ExportInputError(f"{path}: no stations (only a header row)")
        present_optional = [n for n in TRACK_OPTIONAL if n in header]
        cols = _numeric_columns(path, header, body, TRACK_REQUIRED + present_optional, set(TRACK_OPTIONAL))
    _check_plausible_track(path, cols)
    # distance_m (the internal station) increases even where station equations make chainage_m jump
    along = "distance_m" if "distance_m" in cols and np.all(np.isfinite(cols["distance_m"])) else "chainage_m"
    s = cols[along]
    if s.size < 2:
        raise ExportInputError(f"{path}: {s.size} station; a track needs at least two (not a point)")
    if not np.all(np.diff(s) > 0):
        i = int(np.argmax(np.diff(s) <= 0)) + 1
        raise ExportInputError(f"{path}: row {i + 2}, column {along}: {float(s[i])!r} does not increase")
    nan = np.full(s.size, np.nan)
    mm = units.mm_to_m
    track = TrackInput(
        chainage_m=s, E_m=cols["E_m"], N_m=cols["N_m"], H_m=cols["H_m"],
        sigma_E_m=mm(cols["sigma_E_mm"]), sigma_N_m=mm(cols["sigma_N_mm"]), sigma_H_m=mm(cols["sigma_H_mm"]),
        lateral_dev_m=mm(cols.get("lateral_dev_mm", nan)), vertical_dev_m=mm(cols.get("vertical_dev_mm", nan)),
        gauge_m=mm(cols.get("gauge_mm", nan)), cant_m=mm(cols.get("cant_mm", nan)),
        # a track.csv of before 2026-11-26 has neither: the lateral sigma then takes cov 0
        cov_EN_m2=mm(mm(cols["cov_EN_mm2"])) if "cov_EN_mm2" in cols else None,
        sigma_cant_m=mm(cols["sigma_cant_mm"]) if "sigma_cant_mm" in cols else None)
    st = stationing_of_track(s, cols["chainage_m"]) if along == "distance_m" else None
    return TrackFile(track, mm(cols.get("twist_mm", nan)), st, _ignored_column_notes(path, set(cols)))


def _ignored_column_notes(path: Path, read: set[str]) -> list[str]:
    """Notes on header names that look like a track.csv column but are not one ("gauge" for
    gauge_mm): FORMATS.md ignores unknown columns, so the user must hear that the values were not
    read (a misspelled gauge_mm would otherwise pass every gauge tolerance unseen)."""
    import difflib

    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            header = next(csv.reader(f), [])
    except (OSError, UnicodeDecodeError, csv.Error):
        return []
    known = TRACK_REQUIRED + TRACK_OPTIONAL
    notes = []
    for name in (h.strip() for h in header):
        if name in known:
            continue
        close = [c for c in difflib.get_close_matches(name, known, n=1, cutoff=0.6) if c not in read]
        if close:
            notes.append(f"track.csv column {name!r} is not a track.csv column and was ignored (meant {close[0]}?)")
    return notes


def read_fixes_csv(path: Path) -> list[FixRow]:
    """Read the engine's fixes.csv (columns in survey/trackio.py FIX_COLUMNS)."""
    header, body = _read_csv_rows(path)
    cols = _numeric_columns(path, header, body, FIX_NUMERIC, {"innov_E_mm", "innov_N_mm", "innov_H_mm", "nis"})
    for name in ("point", "accepted", "reason"):
        if name not in header:
            raise ExportInputError(f"{path}: missing column {name}")
    ip, ia, ir = header.index("point"), header.index("accepted"), header.index("reason")
    out = []
    mm = units.mm_to_m
    for i, r in enumerate(body):
        acc = (r[ia] if ia < len(r) else "").strip().lower()
        if acc not in ("1", "0", "true", "false", "1.0", "0.0"):
            raise ExportInputError(f"{path}: row {i + 2}, column accepted: expected 1 or 0, got {acc[:20]!r}")
        out.append(FixRow(t_s=float(cols["t_s"][i]), point=csv_read_text(r[ip] if ip < len(r) else ""),
                          E_m=float(cols["E_m"][i]), N_m=float(cols["N_m"][i]), H_m=float(cols["H_m"][i]),
                          innov_E_m=mm(float(cols["innov_E_mm"][i])), innov_N_m=mm(float(cols["innov_N_mm"][i])),
                          innov_H_m=mm(float(cols["innov_H_mm"][i])), nis=float(cols["nis"][i]),
                          accepted=acc in ("1", "true", "1.0"), reason=csv_read_text(r[ir] if ir < len(r) else "")))
    return out


def read_summary_json(path: Path) -> SurveyInfo:
    """Read the engine's summary.json; unknown keys are kept in ``extra``."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ExportInputError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(doc, dict):
        raise ExportInputError(f"{path}: expected a JSON object")
    imu = doc.get("imu") if isinstance(doc.get("imu"), dict) else {}

    def num(d, k, default=math.nan):
        v = d.get(k, default)
        return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else default

    def integer(k):
        v = doc.get(k)
        return int(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None

    known = {"session_dir", "project", "session", "imu", "equipment", "smoother", "fixes_used",
             "fixes_rejected", "rms_innovation_mm", "max_sigma_mm", "step_m", "rail_spacing_m",
             "nominal_gauge_m", "crs", "vertical_datum", "grid_scale_factor", "grid_convergence_deg",
             "grid_combined_scale"}
    equipment = _equipment_from_json(path, doc.get("equipment"))
    return SurveyInfo(
        project=str(doc.get("project", "")), session=str(doc.get("session", "")),
        session_dir=str(doc.get("session_dir", "")), imu_name=str(imu.get("name", "")),
        gyro_bias_instability_deg_h=num(imu, "gyro_bias_instability_deg_h"),
        gyro_arw_deg_sqrt_h=num(imu, "gyro_arw_deg_sqrt_h"), smoother=str(doc.get("smoother", "")),
        equipment=equipment, equipment_source=f"{path} (equipment)" if equipment else "",
        fixes_used=integer("fixes_used"), fixes_rejected=integer("fixes_rejected"),
        rms_innovation_mm=num(doc, "rms_innovation_mm"), max_sigma_mm=num(doc, "max_sigma_mm"),
        step_m=num(doc, "step_m"), rail_spacing_m=num(doc, "rail_spacing_m", 1.500),
        nominal_gauge_m=num(doc, "nominal_gauge_m", 1.435), present=True,
        crs=str(doc.get("crs") or ""), vertical_datum=str(doc.get("vertical_datum") or ""),
        grid_scale_factor=num(doc, "grid_scale_factor"), grid_convergence_deg=num(doc, "grid_convergence_deg"),
        grid_combined_scale=num(doc, "grid_combined_scale"),
        extra={k: v for k, v in doc.items() if k not in known})


def _equipment_from_json(path: Path, eq) -> dict:
    """summary.json ``equipment``: numbers (the lever arm a list of 3) and the IMU name."""
    if eq is None:
        return {}
    if not isinstance(eq, dict):
        raise ExportInputError(f"{path}: key equipment: expected an object")
    out: dict = {}
    for k, v in eq.items():
        if k == "imu_name":
            out[k] = str(v)
        elif k == "prism_lever_arm_m":
            if (not isinstance(v, list) or len(v) != 3
                    or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v)):
                raise ExportInputError(f"{path}: key equipment.prism_lever_arm_m: expected 3 numbers")
            out[k] = [float(x) for x in v]
        elif k in EQUIPMENT:
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ExportInputError(f"{path}: key equipment.{k}: expected a number, got {v!r:.40}")
            out[k] = float(v)
    return out


def session_equipment(session_dir: Path) -> tuple[dict, str]:
    """Equipment figures read from ``session_dir/session.toml`` (for a summary.json without them).

    Returns
    -------
    figures : as :func:`equipment_figures` ({} when session.toml is absent).
    note : "" or why session.toml could not be used (the Summary sheet shows it).
    """
    from survey.sessionio import SessionFormatError, read_session_meta

    toml_path = Path(session_dir) / "session.toml"
    if not toml_path.is_file():
        return {}, ""
    try:
        return equipment_figures(read_session_meta(Path(session_dir))), ""
    except SessionFormatError as e:
        return {}, f"equipment figures not read: {e}"


def _design_table(info: SurveyInfo) -> dict:
    """session.toml's [design] table of the survey's session folder ({} when there is none)."""
    if not info.session_dir:
        return {}
    toml_path = Path(info.session_dir) / "session.toml"
    if not toml_path.is_file():
        return {}
    try:
        doc = tomllib.loads(toml_path.read_text(encoding="utf-8-sig"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ExportInputError(f"{toml_path}: not valid TOML ({e})") from None
    return doc["design"] if isinstance(doc.get("design"), dict) else {}


def design_alignment_path(info: SurveyInfo) -> Path | None:
    """The LandXML file named by the session's session.toml [design] alignment, if any."""
    name = _design_table(info).get("alignment")
    if not name:
        return None
    try:
        return inside(Path(info.session_dir), str(name),
                      f"{Path(info.session_dir) / 'session.toml'}: key design.alignment")
    except ValueError as e:
        raise ExportInputError(str(e)) from None


def design_alignment_name(info: SurveyInfo) -> str | None:
    """session.toml [design] name: the alignment to read from a LandXML file holding several."""
    name = _design_table(info).get("name")
    return str(name) if name else None


#: largest distance between a station's chainage and its point's foot on the design that counts as
#: the same stationing, m (the engine's chainages are within 14 um of the feet; another design's
#: stationing is metres away)
STATIONING_TOLERANCE_M = 0.01
#: deviations recomputed against the design that differ from track.csv's by more are noted, m
DEVIATION_AGREEMENT_M = 0.0005


def add_design(track: TrackInput, landxml_path: Path, rail_spacing_m: float,
               alignment_name: str | None = None,
               notes: list[str] | None = None) -> tuple[TrackInput, Stationing | None]:
    """Fill the design columns of ``track`` from a LandXML alignment evaluated at its chainages
    (internal stations: track.csv's ``distance_m`` when it has one), and its lateral and vertical
    deviations from the measured points' projections onto that alignment.

    The design columns are taken at each point's foot on the alignment, which is its chainage when
    the track was processed against this design (within :data:`STATIONING_TOLERANCE_M`); a track
    processed against another design or none is noted, and keeps its own chainages. Stations beyond
    the alignment's ends get empty design columns and deviations, with a note; a track wholly beyond
    them is refused.

    The design cant (an angle) becomes a rail height difference ``rail_spacing * sin(cant)``,
    positive when the left rail is higher, like the measured cant. The LandXML reader's notes,
    and a word on the chainage when the design has station equations, are appended to ``notes``.

    Returns
    -------
    track : with the design columns.
    stationing : the design's drawing stationing (trolley.stationing.Stationing) when it has
        station equations, else None (the drawing stationing is the internal station).
    """
    from trolley.engine import STATION_END_TOLERANCE_M     # (a station a few mm beyond a run's end is kept)
    from trolley.landxml import AlignmentChoiceError, LandXmlError, decoded_landxml, read_landxml

    try:
        design = read_landxml(decoded_landxml(Path(landxml_path).read_bytes()), alignment_name,
                              rail_spacing_m=rail_spacing_m)
    except OSError as e:
        raise ExportInputError(f"{landxml_path}: cannot read ({e})") from None
    except AlignmentChoiceError as e:
        raise ExportInputError(f"{landxml_path}: {e} (trolley export --design-name NAME)") from None
    except LandXmlError as e:
        raise ExportInputError(f"{landxml_path}: {e}") from None
    alignment = design.alignment
    if notes is not None:
        notes.extend(f"{Path(landxml_path).name}: {n}" for n in design.notes)
        if alignment.stationing is not None and alignment.stationing.equations:
            notes.append(f"{Path(landxml_path).name} has station equations: every chainage shown is the "
                         f"drawing's stationing (track.csv chainage_m); chords, twist bases, wavelength "
                         f"filters and sections run along the distance (track.csv distance_m)")
    name = Path(landxml_path).name
    ch = np.asarray(track.chainage_m, dtype=float)
    lo, hi = alignment.start_chainage_m, alignment.end_chainage_m
    # the deviations are the measured points' offsets from THIS design at their foot points (the
    # engine's, when it is the design the track was processed with); the design columns are taken
    # there too, so another design, or one on other stations, is never compared at the wrong place
    p = alignment.project(track.E_m, track.N_m, track.H_m)
    foot = np.asarray(p.chainage_m, dtype=float)
    within = (foot >= lo - STATION_END_TOLERANCE_M) & (foot <= hi + STATION_END_TOLERANCE_M)
    if not within.any():
        raise ExportInputError(f"{landxml_path}: the track ({ch[0]:.3f}-{ch[-1]:.3f} m) lies wholly beyond the "
                               f"ends of this design ({lo:.3f}-{hi:.3f} m): another design?")
    apart = np.where(within, np.abs(foot - ch), 0.0)
    same_stations = bool(apart.max() <= STATIONING_TOLERANCE_M)
    lateral = np.where(within, np.asarray(p.lateral_m, dtype=float), np.nan)
    vertical = np.where(within, np.asarray(p.vertical_m, dtype=float), np.nan) if alignment.profile is not None \
        else np.full(ch.shape, np.nan)
    if notes is not None:
        if not same_stations:
            i = int(np.argmax(apart))
            notes.append(f"{name}: the track's chainages are not this design's stationing (the station at "
                         f"{ch[i]:.3f} m lies at the design's {foot[i]:.3f} m, {apart[i]:.3f} m apart; the track was "
                         "processed against another design or none): design columns and deviations are taken at "
                         "each point's foot on this design; the chainages shown are the track's")
        if not within.all():
            out = ch[~within]
            notes.append(f"{name}: {out.size} station(s) at chainage {out.min():.3f}-{out.max():.3f} m lie beyond the "
                         f"ends of the design ({lo:.3f}-{hi:.3f} m): their design columns and deviations are empty")
    devs = {}
    for what, new, old in (("lateral", lateral, track.lateral_dev_m), ("vertical", vertical, track.vertical_dev_m)):
        old = np.asarray(old, dtype=float)
        both = np.isfinite(new) & np.isfinite(old)
        worst = float(np.max(np.abs(new[both] - old[both]))) if both.any() else 0.0
        if same_stations and both.any() and worst <= DEVIATION_AGREEMENT_M and np.array_equal(both, np.isfinite(new)):
            devs[what] = np.where(within, old, np.nan)    # the engine's, from the unrounded coordinates
            continue
        devs[what] = new
        if notes is None:
            continue
        if worst > DEVIATION_AGREEMENT_M:
            notes.append(f"{name}: {what} deviations from this design differ from track.csv's by up to "
                         f"{1e3 * worst:.1f} mm (the track was processed against another design): the sheet shows "
                         "this design's")
        elif np.isfinite(new).any() and not np.isfinite(old).any():
            notes.append(f"{name}: track.csv has no {what} deviations: they are computed against this design")
    d = alignment.evaluate(ch if same_stations else np.where(within, foot, lo))
    nan = np.where(within, 1.0, np.nan)
    track.design_E_m, track.design_N_m = d.E_m * nan, d.N_m * nan
    track.design_H_m = d.H_m * nan if alignment.profile is not None else np.full(d.H_m.shape, np.nan)
    track.design_cant_m = rail_spacing_m * np.sin(d.cant_rad) * nan
    track.lateral_dev_m, track.vertical_dev_m = devs["lateral"], devs["vertical"]
    if not same_stations:
        return track, None
    st = alignment.stationing
    return track, (st if st is not None and st.equations else None)
