"""The header block of the survey deliverables: the fields a client signs off, and their checks.

Every sheet of the workbook and the cover of the PDF report start with the same block: project,
line and track, chainage range, survey date and time span, crew, the instruments (make, model,
serial number, calibration date of the total station, the IMU and the trolley), rail
temperature, coordinate system and height datum, software version and the tolerance set with its
source. Fields the crew gives are kept in the project store (``trolley project set KEY VALUE``,
:data:`HEADER_FIELDS`); the rest come from the survey itself. A field nobody gave reads
:data:`NOT_GIVEN`, never an internal note or a temporary path.

No paper section: this is the deliverable's form (shared/research/protocols.md 6, what GRP and
GEDO survey sheets carry).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from datetime import date

#: what a field nobody gave reads
NOT_GIVEN = "not given"


@dataclass(frozen=True)
class HeaderField:
    """A header field the crew sets with ``trolley project set``.

    Attributes
    ----------
    label : text on the sheet.
    kind : "text", "date" (ISO 8601 YYYY-MM-DD) or "celsius" (a temperature, -60..90).
    """

    label: str
    kind: str = "text"


#: keys of ``trolley project set KEY VALUE``, in header order
HEADER_FIELDS: dict[str, HeaderField] = {
    "line": HeaderField("Line"),
    "track": HeaderField("Track"),
    "client": HeaderField("Client"),
    "crew": HeaderField("Crew / operator"),
    "totalstation": HeaderField("Total station make and model"),
    "totalstation_serial": HeaderField("Total station serial number"),
    "totalstation_calibrated": HeaderField("Total station calibrated", "date"),
    "imu": HeaderField("IMU make and model"),
    "imu_serial": HeaderField("IMU serial number"),
    "imu_calibrated": HeaderField("IMU calibrated", "date"),
    "trolley": HeaderField("Trolley make and model"),
    "trolley_serial": HeaderField("Trolley serial number"),
    "trolley_calibrated": HeaderField("Trolley (gauge, cant) calibrated", "date"),
    "rail_temperature_c": HeaderField("Rail temperature [°C]", "celsius"),
}
#: header entries the field record takes from the project's CRS (``trolley project set-crs``), not
#: from ``project set``: key -> label
CRS_FIELDS = {"coordinate_system": "Coordinate system", "height_datum": "Height datum",
              "grid": "Grid convergence and scale"}

_MAX_LEN = 200
#: rail temperatures a header may hold, °C (`project set rail_temperature_c`)
RAIL_TEMPERATURE_RANGE_C = (-60.0, 90.0)
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def check_header_value(key: str, value: str) -> str:
    """The value to store for a header field (stripped), or ValueError saying what is wrong.

    An empty value clears the field (it reads :data:`NOT_GIVEN` again).
    """
    if key not in HEADER_FIELDS:
        raise ValueError(f"unknown key {key!r}; the keys are: {', '.join(HEADER_FIELDS)}")
    text = str(value).strip()
    if not text:
        return ""
    if len(text) > _MAX_LEN:
        raise ValueError(f"{key}: {len(text)} characters, at most {_MAX_LEN}")
    if _CONTROL.search(text):
        raise ValueError(f"{key}: control characters (tab, newline, ...) are not allowed")
    kind = HEADER_FIELDS[key].kind
    if kind == "date":
        try:
            date.fromisoformat(text)
        except ValueError:
            raise ValueError(f"{key}: {text!r} is not a date as YYYY-MM-DD") from None
        if not re.fullmatch(r"\d{4}-\d{2}-\d{2}", text):
            raise ValueError(f"{key}: {text!r} is not a date as YYYY-MM-DD")
    elif kind == "celsius":
        try:
            number = text.replace("°C", "").replace("C", "").strip()
            if "_" in number:       # Python's float() takes digit grouping ("1_0" = 10): not a reading
                raise ValueError(number)
            t = float(number)
        except ValueError:
            raise ValueError(f"{key}: {text!r} is not a temperature in °C (a number)") from None
        from survey.limits import check_finite

        # the messages every number on the command line gets ("nan" was "outside -60..90 °C")
        check_finite(t, key, minimum=RAIL_TEMPERATURE_RANGE_C[0], maximum=RAIL_TEMPERATURE_RANGE_C[1], why="°C")
        text = f"{t:g}"
    return text


def software_version() -> str:
    """``trolley-survey X.Y.Z`` of the installed package (:func:`survey.version.version`)."""
    from survey.version import DISTRIBUTION, version

    return f"{DISTRIBUTION} {version()}"


def header_rows(rep) -> list[tuple[str, str]]:
    """The header block of a survey report as (label, text) rows.

    Parameters
    ----------
    rep : survey.track_table.SurveyReport (its ``record`` may be None: a track processed
        without a field session; the crew's fields then read :data:`NOT_GIVEN`).
    """
    from survey.plots import km_label

    info, rec = rep.info, rep.record
    given = dict(rec.header) if rec is not None else {}

    def field(key: str) -> str:
        return given.get(key) or NOT_GIVEN

    # coordinate system and datum: the processing's own (SurveyInfo.crs / vertical_datum, when the
    # engine records them), else the session's (field record, from `trolley project set-crs`)
    crs = str(getattr(info, "crs", "") or "") or field("coordinate_system")
    datum = str(getattr(info, "vertical_datum", "") or "") or field("height_datum")
    grid = field("grid")
    if math.isfinite(getattr(info, "grid_convergence_deg", math.nan)):  # the processing's own, at the fixes
        grid = (f"convergence {info.grid_convergence_deg:+.6f} deg, point scale factor {info.grid_scale_factor:.9f}, "
                f"combined scale {info.grid_combined_scale:.9f} at the site")
    s = rep.geometry.chainage_m
    span = time_span(rec.start_utc, rec.end_utc) if rec is not None else NOT_GIVEN
    rows = [
        ("Project", info.project or (rec.project if rec is not None else "") or NOT_GIVEN),
        ("Session", info.session or (rec.session if rec is not None else "") or NOT_GIVEN),
        ("Line", field("line")),
        ("Track", field("track")),
        ("Client", field("client")),
        ("Chainage", f"{km_label(rep.station(float(s[0])), 3)} to {km_label(rep.station(float(s[-1])), 3)} ({s.size} stations, "
                     f"step {rep.geometry.step_m:g} m)"),
        ("Survey date and time", span),
        ("Crew / operator", field("crew")),
    ]
    for dev in ("totalstation", "imu", "trolley"):
        make = field(dev)
        if dev == "imu" and make == NOT_GIVEN and (info.equipment.get("imu_name") or info.imu_name):
            make = f"{NOT_GIVEN} (figures of the preset {info.equipment.get('imu_name') or info.imu_name!r} used)"
        rows.append((HEADER_FIELDS[dev].label, make))
        rows.append((HEADER_FIELDS[f"{dev}_serial"].label, field(f"{dev}_serial")))
        rows.append((HEADER_FIELDS[f"{dev}_calibrated"].label, field(f"{dev}_calibrated")))
    rows += [
        (HEADER_FIELDS["rail_temperature_c"].label, field("rail_temperature_c")),
        ("Coordinate system", crs),
        ("Height datum", datum),
        ("Grid convergence and scale", grid),
        ("Software", software_version()),
        ("Tolerance set", f"{rep.tolerances.name}: {rep.tolerances.title}"),
        ("Tolerance source", _tolerance_source(rep.tolerances)),
    ]
    return rows


def _grid(info) -> str:
    """The processing's grid convergence and combined scale (summary.json), '' when not known."""
    conv = getattr(info, "grid_convergence_deg", math.nan)
    scale = getattr(info, "grid_combined_scale", math.nan)
    if not (math.isfinite(conv) and math.isfinite(scale)):
        return ""
    return f"convergence {conv:+.6f} deg, scale {scale:.9f} (site)"


def time_span(start_utc: str, end_utc: str) -> str:
    """'2026-11-26 08:02 to 11:47 UTC' (the date once when both are on one day) from ISO 8601 texts."""
    from datetime import datetime, timezone

    try:
        a, b = (datetime.fromisoformat(x).astimezone(timezone.utc) for x in (start_utc, end_utc))
    except (TypeError, ValueError):
        return NOT_GIVEN
    end = b.strftime("%H:%M") if a.date() == b.date() else b.strftime("%Y-%m-%d %H:%M")
    return f"{a.strftime('%Y-%m-%d %H:%M')} to {end} UTC"


def _tolerance_source(tol) -> str:
    """Where the set comes from (the built-in file, or the user's file by name), and whether
    any limit is only an example; each limit's own source is on the Summary sheet."""
    from pathlib import PurePath

    origin = tol.origin or ""
    where = (f"built-in set {origin.split(':', 1)[1]}" if origin.startswith("built-in:")
             else f"file {PurePath(origin).name}" if origin else NOT_GIVEN)
    n_ex = sum(1 for lim in tol.limits if lim.example)
    return f"{where}: {len(tol.limits) - n_ex} limits with a cited source, {n_ex} example values"


__all__ = ["NOT_GIVEN", "HeaderField", "HEADER_FIELDS", "CRS_FIELDS", "check_header_value", "header_rows", "software_version", "time_span"]
