"""Read and write the raw stop-and-go session folder (FORMATS.md section 1), and truth.csv.

The folder is a contract: ``session.toml``, ``imu.csv``, ``odometer.csv``, ``fixes.csv`` and the
optional ``gauge.csv`` (and the LandXML design it names). Reading is strict and fast: the CSVs
go through pandas' C parser with float dtypes and are validated vectorised; only when something
is wrong is the file re-read as text to name the first bad cell. Every error is a
:class:`SessionFormatError` whose message names the file, the row as a spreadsheet shows it
(the header is row 1, the first data row is row 2) and the column (or the TOML key).

Writing is atomic: the whole folder is written into a temporary sibling and renamed into place,
so a crash never leaves a partial session. Numbers are written so that reading them back gives
the same doubles: times, odometer distances, fixes and gauge exactly (shortest round-trip
repr); the IMU rates and specific forces with 12 significant digits (1e-17 rad/s on a 1e-5 rad/s
rate, far below any sensor's resolution) unless ``exact=True``. See docs/simulator.md, "Files".
"""
from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
import tomllib
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from trolley import units
from trolley.numbertext import parse_number
from trolley.sensors import ImuFigures, OdometerFigures
from trolley.session import Fixes, RawSession, SessionMeta, TrolleyGeometry

from survey.atomicwrite import folder_mode, write_text_atomic, write_with
from survey.names import is_relative_inside

__all__ = [
    "SessionFormatError",
    "FORMAT_ID",
    "read_session",
    "read_session_meta",
    "write_session",
    "write_session_meta",
    "session_toml_text",
    "write_truth_csv",
    "read_truth_csv",
    "read_design",
]

#: Value of the ``format`` key this module reads and writes.
FORMAT_ID = "trolley-raw-session/1"

IMU_COLUMNS = ["t_s", "wx_rad_s", "wy_rad_s", "wz_rad_s", "fx_m_s2", "fy_m_s2", "fz_m_s2"]
ODOMETER_COLUMNS = ["t_s", "distance_m"]
FIXES_COLUMNS = ["t_s", "point", "E_m", "N_m", "H_m"]
FIXES_SIGMA_COLUMNS = ["sigma_E_m", "sigma_N_m", "sigma_H_m"]
#: optional covariances between a fix's axes (docs/engine.md, step 6): a polar measurement's E and N
#: are correlated by its line of sight; written by the field session, 0 when absent
FIXES_COV_COLUMNS = ["cov_EN_m2", "cov_EH_m2", "cov_NH_m2"]
GAUGE_COLUMNS = ["t_s", "gauge_m"]
TRUTH_COLUMNS = ["chainage_m", "E_m", "N_m", "H_m", "roll_rad", "pitch_rad", "yaw_rad",
                 "gauge_m", "cant_mm", "lateral_mm", "vertical_mm"]

_EXACT = "%r"          # shortest repr that reads back to the same double
_SENSOR = "%.12g"      # IMU samples: 12 significant digits


class SessionFormatError(ValueError):
    """A raw session that breaks FORMATS.md; the message names file, row and column/key."""


# ------------------------------------------------------------------------------------------
# session.toml
# ------------------------------------------------------------------------------------------
_MISSING = object()


class _Toml:
    """Typed access to the parsed session.toml with key-naming errors."""

    def __init__(self, data: dict, fname: str) -> None:
        self.data = data
        self.fname = fname

    def error(self, key: str, what: str) -> SessionFormatError:
        return SessionFormatError(f"{self.fname}: key {key}: {what}")

    def raw(self, key: str):
        node = self.data
        parts = key.split(".")
        for i, part in enumerate(parts):
            if not isinstance(node, dict):
                raise self.error(".".join(parts[:i]), "must be a table")
            if part not in node:
                return _MISSING
            node = node[part]
        return node

    def table(self, key: str) -> bool:
        v = self.raw(key)
        if v is _MISSING:
            return False
        if not isinstance(v, dict):
            raise self.error(key, f"must be a table, got {type(v).__name__}")
        return True

    def float(self, key: str, default=_MISSING, *, finite: bool = True, min_value=None,
              positive: bool = False, max_value=None) -> float:
        v = self.raw(key)
        if v is _MISSING:
            if default is _MISSING:
                raise self.error(key, "missing (required)")
            return default
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.error(key, f"must be a number, got {type(v).__name__} {v!r}")
        v = float(v)
        if finite and not math.isfinite(v):
            raise self.error(key, f"must be finite, got {v!r}")
        if min_value is not None and v < min_value:
            raise self.error(key, f"must be >= {min_value}, got {v!r}")
        if positive and not v > 0:
            raise self.error(key, f"must be > 0, got {v!r}")
        if max_value is not None and v > max_value:
            raise self.error(key, f"must be <= {max_value:g} (beyond any instrument of this kind), got {v!r}")
        return v

    def vector(self, key: str, default) -> np.ndarray:
        v = self.raw(key)
        if v is _MISSING:
            return np.array(default, dtype=float)
        if (not isinstance(v, list) or len(v) != 3
                or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v)):
            raise self.error(key, f"must be a list of 3 numbers, got {v!r}")
        arr = np.array(v, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise self.error(key, f"must be finite, got {v!r}")
        return arr

    def string(self, key: str, default=_MISSING) -> str:
        v = self.raw(key)
        if v is _MISSING:
            if default is _MISSING:
                raise self.error(key, "missing (required)")
            return default
        if not isinstance(v, str):
            raise self.error(key, f"must be a string, got {type(v).__name__} {v!r}")
        return v

    def boolean(self, key: str, default: bool) -> bool:
        v = self.raw(key)
        if v is _MISSING:
            return default
        if not isinstance(v, bool):
            raise self.error(key, f"must be true or false, got {v!r}")
        return v


def _f(x) -> float:
    return float(x)


def _fix_sigma(t) -> float:
    """[totalstation] sigma_m within :data:`SIGMA_RANGE_M`, as a fixes.csv sigma must be."""
    v = t.float("totalstation.sigma_m", 0.0006, positive=True)
    if not SIGMA_RANGE_M[0] <= v <= SIGMA_RANGE_M[1]:
        raise t.error("totalstation.sigma_m", f"must be within {SIGMA_RANGE_M[0]:g}..{SIGMA_RANGE_M[1]:g} m (a fix's "
                                              f"1-sigma), got {v!r}")
    return v


def _parse_meta(text: str, fname: str = "session.toml") -> SessionMeta:
    try:
        data = tomllib.loads(text.removeprefix("\ufeff"))   # (a BOM, as Notepad writes)
    except tomllib.TOMLDecodeError as exc:
        raise SessionFormatError(f"{fname}: not valid TOML: {exc}") from None
    t = _Toml(data, fname)
    fmt = t.string("format")
    if fmt.split("/")[0] != FORMAT_ID.split("/")[0] or fmt.split("/")[-1].split(".")[0] != "1":
        raise t.error("format", f"unsupported format {fmt!r}, expected {FORMAT_ID!r}")
    for tab in ("site", "trolley", "imu", "odometer", "totalstation", "alignment", "design"):
        t.table(tab)
    crs = t.string("site.crs", None)
    if crs is not None:
        from trolley.projection import CrsError, crs_info
        try:
            crs = crs_info(crs).text
        except CrsError as exc:
            raise t.error("site.crs", str(exc)) from None
    vertical_datum = t.string("site.vertical_datum", None)
    # with a CRS the latitude comes from it and the fixes (trolley.projection.session_site)
    latitude_deg = t.float("site.latitude_deg", float("nan") if crs else _MISSING)
    from trolley.earth import MAX_LATITUDE_DEG

    if abs(latitude_deg) > MAX_LATITUDE_DEG:
        raise t.error("site.latitude_deg", f"must be within -{MAX_LATITUDE_DEG:g}..{MAX_LATITUDE_DEG:g} (the "
                                           f"alignment has no north near the poles), got {latitude_deg!r}")
    dflt = TrolleyGeometry()
    trolley = TrolleyGeometry(
        prism_lever_arm_m=t.vector("trolley.prism_lever_arm_m", dflt.prism_lever_arm_m),
        imu_misalignment_rad=t.vector("trolley.imu_misalignment_rad", dflt.imu_misalignment_rad),
        rail_spacing_m=t.float("trolley.rail_spacing_m", dflt.rail_spacing_m, positive=True),
        nominal_gauge_m=t.float("trolley.nominal_gauge_m", dflt.nominal_gauge_m, positive=True),
    )
    for key, value, limit, unit in (("trolley.prism_lever_arm_m", trolley.prism_lever_arm_m, MAX_LEVER_ARM_M, "m"),
                                    ("trolley.imu_misalignment_rad", trolley.imu_misalignment_rad,
                                     MAX_MISALIGNMENT_RAD, "rad")):
        if np.max(np.abs(value)) > limit:
            raise t.error(key, f"each component must be within +-{limit:g} {unit} (a trolley's size; metres, not "
                               f"millimetres?), got {list(map(float, value))}")
    imu = None
    if t.table("imu"):
        imu = ImuFigures(
            # (ceilings far above any IMU: 1e300 deg/h overflowed later, naming no key)
            gyro_bias_instability_rad_s=_f(units.deg_h_to_rad_s(
                t.float("imu.gyro_bias_instability_deg_h", min_value=0.0, max_value=1e4))),
            gyro_arw_rad_sqrt_s=_f(units.deg_sqrt_h_to_rad_sqrt_s(
                t.float("imu.gyro_arw_deg_sqrt_h", min_value=0.0, max_value=1e3))),
            accel_bias_m_s2=_f(units.ug_to_m_s2(t.float("imu.accel_bias_ug", min_value=0.0, max_value=1e6))),
            accel_vrw_m_s_sqrt_s=_f(units.ug_to_m_s2(
                t.float("imu.accel_vrw_ug_sqrt_hz", 0.0, min_value=0.0, max_value=1e6))),
            gyro_scale_factor=t.float("imu.gyro_scale_factor_ppm", 0.0, min_value=0.0, max_value=1e5) * 1e-6,
            name=t.string("imu.name", "custom"),
            gyrocompassing=t.boolean("imu.gyrocompassing", True),
        )
    od = OdometerFigures()
    odometer = OdometerFigures(
        scale_noise_per_sqrt_s=t.float("odometer.scale_noise_per_sqrt_s",
                                       od.scale_noise_per_sqrt_s, min_value=0.0, max_value=0.1),
        scale_error=t.float("odometer.scale_error", od.scale_error, min_value=0.0, max_value=0.1),
        resolution_m=t.float("odometer.resolution_m", od.resolution_m, min_value=0.0, max_value=1.0),
    )
    heading_deg = t.float("alignment.initial_heading_deg", float("nan"), finite=False)
    if math.isinf(heading_deg):
        raise t.error("alignment.initial_heading_deg", "must be finite or nan")
    design = t.string("design.alignment", None) if t.raw("design.alignment") is not _MISSING \
        else None
    if design is not None:
        if not is_relative_inside(design):
            raise t.error("design.alignment", f"must be a relative path inside the session "
                                              f"folder, got {design!r}")
    return SessionMeta(
        latitude_rad=float(units.deg_to_rad(latitude_deg)),
        height_m=t.float("site.height_m", 0.0),
        trolley=trolley,
        imu=imu,
        odometer=odometer,
        fix_sigma_m=_fix_sigma(t),
        static_s=t.float("alignment.static_s", 900.0, min_value=0.0),
        initial_heading_rad=float(units.deg_to_rad(heading_deg)),
        design_alignment=design,
        design_alignment_name=(t.string("design.name", None)
                               if t.raw("design.name") is not _MISSING else None),
        crs=crs,
        vertical_datum=vertical_datum,
    )


def _toml_float(x: float) -> str:
    x = float(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return repr(x)


def _toml_converted(x: float) -> str:
    """A unit-converted value: 15 significant digits (0.03, not 0.029999999999999995)."""
    x = float(x)
    return _toml_float(float(f"{x:.15g}") if math.isfinite(x) else x)


def _toml_vector(v) -> str:
    return "[" + ", ".join(_toml_float(x) for x in np.asarray(v, dtype=float).ravel()) + "]"


def session_toml_text(meta: SessionMeta) -> str:
    """The ``session.toml`` text of ``meta`` (all keys of FORMATS.md sec. 1, plus extensions).

    Extensions (optional keys this project adds; readers that do not know them ignore them):
    ``[site] crs, vertical_datum`` (with a crs, ``latitude_deg`` may be left out: it is derived
    from the CRS and the fixes), ``[imu] accel_vrw_ug_sqrt_hz, gyro_scale_factor_ppm, name, gyrocompassing`` and
    ``[odometer] scale_error, resolution_m``.
    """
    tr = meta.trolley
    lines = [
        f'format = "{FORMAT_ID}"',
        "",
        "[site]",
    ]
    if math.isfinite(meta.latitude_rad) or not meta.crs:
        lines.append(f"latitude_deg = {_toml_converted(units.rad_to_deg(meta.latitude_rad))}")
    lines.append(f"height_m = {_toml_float(meta.height_m)}")
    if meta.crs:
        lines.append(f"crs = {json.dumps(meta.crs, ensure_ascii=False)}")
    if meta.vertical_datum:
        lines.append(f"vertical_datum = {json.dumps(meta.vertical_datum, ensure_ascii=False)}")
    lines += [
        "",
        "[trolley]",
        f"prism_lever_arm_m = {_toml_vector(tr.prism_lever_arm_m)}",
        f"imu_misalignment_rad = {_toml_vector(tr.imu_misalignment_rad)}",
        f"rail_spacing_m = {_toml_float(tr.rail_spacing_m)}",
        f"nominal_gauge_m = {_toml_float(tr.nominal_gauge_m)}",
        "",
    ]
    if meta.imu is not None:
        imu = meta.imu
        lines += [
            "[imu]",
            f"gyro_bias_instability_deg_h = "
            f"{_toml_converted(units.rad_s_to_deg_h(imu.gyro_bias_instability_rad_s))}",
            f"gyro_arw_deg_sqrt_h = "
            f"{_toml_converted(units.rad_sqrt_s_to_deg_sqrt_h(imu.gyro_arw_rad_sqrt_s))}",
            f"accel_bias_ug = {_toml_converted(units.m_s2_to_ug(imu.accel_bias_m_s2))}",
            f"accel_vrw_ug_sqrt_hz = {_toml_converted(units.m_s2_to_ug(imu.accel_vrw_m_s_sqrt_s))}",
            f"gyro_scale_factor_ppm = {_toml_converted(imu.gyro_scale_factor * 1e6)}",
            f"name = {json.dumps(imu.name, ensure_ascii=False)}",
            f"gyrocompassing = {'true' if imu.gyrocompassing else 'false'}",
            "",
        ]
    od = meta.odometer
    lines += [
        "[odometer]",
        f"scale_noise_per_sqrt_s = {_toml_float(od.scale_noise_per_sqrt_s)}",
        f"scale_error = {_toml_float(od.scale_error)}",
        f"resolution_m = {_toml_float(od.resolution_m)}",
        "",
        "[totalstation]",
        f"sigma_m = {_toml_float(meta.fix_sigma_m)}",
        "",
        "[alignment]",
        f"static_s = {_toml_float(meta.static_s)}",
        f"initial_heading_deg = {_toml_converted(units.rad_to_deg(meta.initial_heading_rad))}",
        "",
    ]
    if meta.design_alignment is not None:
        lines += ["[design]", f"alignment = {json.dumps(meta.design_alignment, ensure_ascii=False)}"]
        if meta.design_alignment_name is not None:
            lines.append(f"name = {json.dumps(meta.design_alignment_name, ensure_ascii=False)}")
        lines.append("")
    return "\n".join(lines)


def read_session_meta(folder: Path) -> SessionMeta:
    """Parse ``folder/session.toml``.

    Raises
    ------
    SessionFormatError
        Missing file, bad TOML, missing required key or wrong type (the message names the key).
    """
    path = Path(folder) / "session.toml"
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise SessionFormatError(f"{path}: file missing") from None
    except UnicodeDecodeError as exc:
        raise SessionFormatError(f"{path}: not UTF-8 ({exc})") from None
    return _parse_meta(text, str(path))


def write_session_meta(path: Path, meta: SessionMeta) -> None:
    """Write ``session.toml`` (atomic: temp file + os.replace)."""
    write_text_atomic(Path(path), session_toml_text(meta))


# ------------------------------------------------------------------------------------------
# CSV reading
# ------------------------------------------------------------------------------------------
def _row(i: int) -> int:
    """0-based data index -> row number as a spreadsheet shows it (header = row 1)."""
    return int(i) + 2


def _header(path: Path) -> list[str]:
    import pandas as pd

    try:
        cols = pd.read_csv(path, nrows=0, encoding="utf-8-sig", engine="c").columns
    except FileNotFoundError:
        raise SessionFormatError(f"{path}: file missing") from None
    except UnicodeDecodeError:
        raise _utf8_error(path) from None
    except pd.errors.EmptyDataError:
        raise SessionFormatError(f"{path}: row 1: empty file, no header row") from None
    except pd.errors.ParserError as exc:
        raise SessionFormatError(f"{path}: row 1: cannot parse header ({exc})") from None
    return [str(c) for c in cols]


def _utf8_error(path: Path) -> SessionFormatError:
    """Name the row of the first byte that is not UTF-8."""
    data = path.read_bytes()
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        row = data.count(b"\n", 0, exc.start) + 1
        return SessionFormatError(f"{path}: row {row}: not UTF-8 (byte {exc.object[exc.start]:#04x}"
                                  f" at file offset {exc.start})")
    return SessionFormatError(f"{path}: not UTF-8")


def _require(path: Path, header: list[str], required: list[str]) -> dict[str, str]:
    """Map required column names to the header names (surrounding blanks tolerated)."""
    stripped = {}
    for h in header:
        stripped.setdefault(h.strip(), h)
    missing = [c for c in required if c not in stripped]
    if missing:
        raise SessionFormatError(f"{path}: row 1: missing required column "
                                 f"{', '.join(missing)} (header has {', '.join(header)})")
    return stripped


def line_spans(data: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the lines of a text file's bytes are, vectorised: (starts, ends, used), ``ends``
    exclusive (at the line feed), ``used`` False for a blank line (nothing but spaces, tabs or a
    carriage return), which pandas and the csv readers skip. For readers that must count lines
    or cells as an editor shows them without a Python loop over the rows."""
    ends = np.r_[np.flatnonzero(data == ord("\n")), data.size]
    starts = np.r_[0, ends[:-1] + 1]
    printable = np.r_[0, np.cumsum(data > ord(" "))]
    return starts, ends, printable[ends] - printable[starts] > 0


def implicit_index_problem(path: Path, df) -> str | None:
    """The message for rows wider than the header that pandas took as an index, or None.

    When *every* data row has more cells than the header (decimal commas throughout: "0,5"),
    pandas reads the first cells as the index without a word and every column shifts; the
    files' values would be silently wrong (review of 2026-11-26: an odometer.csv read so ended
    as a CRS error). Every reader of the recorded CSV files (this module's, survey.tgms_io's)
    checks the frame pandas gave it with this."""
    import pandas as pd

    if isinstance(df.index, pd.RangeIndex):
        return None
    n = len(df.columns)
    return (f"{path}: row 2: {n + df.index.nlevels} cells, the header has {n} columns (a decimal comma? use a "
            "point: 0.5)")


def _check_no_implicit_index(path: Path, df) -> None:
    problem = implicit_index_problem(path, df)
    if problem:
        raise SessionFormatError(problem)


def _parser_error(path: Path, exc: Exception) -> SessionFormatError:
    import re

    msg = str(exc)
    m = re.search(r"line (\d+)", msg)
    where = f"row {m.group(1)}: " if m else ""
    q = re.search(r"EOF inside string starting at row (\d+)", msg)
    if q:
        # pandas counts that row from 0 with the header: a spreadsheet's row is one more
        return SessionFormatError(f"{path}: row {int(q.group(1)) + 1}: a quote (\") opens a text that no "
                                  "quote closes before the end of the file (a stray quote in a cell?)")
    return SessionFormatError(f"{path}: {where}malformed CSV ({msg.strip()})")


#: Largest magnitude a cell of these columns can plausibly hold, SI units. A finite but absurd
#: value (1e308 in an IMU cell) would otherwise pass the finite check and end as a garbage or
#: empty track; the limits are far beyond any real instrument: a navigation gyro's range is
#: below 35 rad/s (2000 deg/s), an accelerometer's below 200 g, a survey below 10 000 km.
PLAUSIBLE_ABS = {
    "t_s": 1e10, "wx_rad_s": 100.0, "wy_rad_s": 100.0, "wz_rad_s": 100.0,
    "fx_m_s2": 2000.0, "fy_m_s2": 2000.0, "fz_m_s2": 2000.0, "distance_m": 1e7, "gauge_m": 10.0,
    "chainage_m": 1e8, "E_m": 1e8, "N_m": 1e8, "H_m": 1e5,
}
#: Largest prism lever arm component, m, and IMU mounting misalignment, rad, of a trolley
MAX_LEVER_ARM_M = 10.0
MAX_MISALIGNMENT_RAD = 0.1
#: A fix's 1-sigma, m: below 1 micrometre no instrument measures, above 100 m it is no fix.
SIGMA_RANGE_M = (1e-6, 100.0)
#: Rows re-read as text at a time when a bad cell must be found (bounded memory).
_LOCATE_CHUNK_ROWS = 200_000


def _cell_problem(value: str) -> str:
    value = value.strip()
    if value == "":
        return "empty value"
    if value.lower().lstrip("+-") in ("nan", "inf", "infinity"):
        return f"{value!r} is not a finite number"
    try:
        parse_number(value)
    except ValueError as exc:
        return str(exc)
    return f"{value!r} is not a number"


def _text_rows(path: Path, header: list[str], cols: list[str], first: int, nrows: int):
    """Rows ``first`` .. ``first + nrows`` (0-based data rows) of ``cols`` as text."""
    import pandas as pd

    return pd.read_csv(path, header=None, names=header, usecols=cols, skiprows=first + 1, nrows=nrows,
                       dtype=str, keep_default_na=False, skip_blank_lines=False, encoding="utf-8-sig",
                       engine="c")


def _first_bad_text(path: Path, header: list[str], names: dict[str, str], numeric: list[str],
                    first: int, nrows: int) -> SessionFormatError | None:
    """The first non-numeric or non-finite cell of rows ``first`` .. ``first + nrows``, or None."""
    import pandas as pd

    raw = _text_rows(path, header, [names[c] for c in numeric], first, nrows)
    best = None
    for c in numeric:
        text = raw[names[c]]
        vals = pd.to_numeric(text.str.strip(), errors="coerce").to_numpy(dtype=float)
        bad = ~np.isfinite(vals)
        if np.any(bad):
            i = int(np.argmax(bad))
            if best is None or i < best[0]:
                best = (i, c, text.iloc[i])
    if best is None:
        return None
    i, c, value = best
    return SessionFormatError(f"{path}: row {_row(first + i)}, column {c}: {_cell_problem(value)}")


_BLOCK_BYTES = 1 << 24


def _line_at(path: Path, line: int) -> bytes | None:
    """The bytes of line ``line`` (0 = the header) without its end, None past the end.

    Newlines are counted block by block (``bytes.count`` runs at memory speed), so finding one row
    of a 500 MB file costs a fraction of a second and one block of memory, not a parse.
    """
    seen = 0
    with open(path, "rb") as fh:
        carry = b""
        while True:
            block = fh.read(_BLOCK_BYTES)
            if not block:
                return carry if seen == line and carry else None
            block = carry + block
            n = block.count(b"\n")
            if seen + n > line:
                start = 0
                for _ in range(line - seen):
                    start = block.index(b"\n", start) + 1
                return block[start:block.index(b"\n", start)].rstrip(b"\r")
            seen += n
            carry = block[block.rfind(b"\n") + 1:]


def _bad_row_text(path: Path, header: list[str], names: dict[str, str], numeric: list[str],
                  row: int, raw: bytes | None = None) -> SessionFormatError | None:
    """Describe the first non-numeric or non-finite cell of data row ``row`` (0-based), its text
    ``raw`` or read by :func:`_line_at`; None if that row has none (or cannot be split)."""
    import csv

    raw = _line_at(path, row + 1) if raw is None else raw
    if raw is None:
        return None
    try:
        cells = next(csv.reader([raw.decode("utf-8")]))
    except (UnicodeDecodeError, csv.Error, StopIteration):
        return None
    for c in numeric:
        j = header.index(names[c])
        text = cells[j] if j < len(cells) else ""
        try:
            ok = np.isfinite(parse_number(text.strip()))
        except ValueError:
            ok = False
        if not ok:
            return SessionFormatError(f"{path}: row {_row(row)}, column {c}: {_cell_problem(text)}")
    return None


#: Most places a token may be looked at before the scan gives up (a token such as "e" occurs in
#: every exponent; then the block-wise re-read is the faster way).
_MAX_TOKEN_HITS = 10_000
_CELL_EDGE = frozenset(b',"\t \r\n')


def _find_token_row(path: Path, token: str) -> tuple[int, bytes] | None:
    """(0-based data row, line bytes) of the first cell that is exactly ``token`` (the text pandas
    could not convert, which its message quotes), found in one pass over the file's blocks with
    ``bytes.find`` and ``bytes.count``; None when not found or too common to look for."""
    tok = token.encode("utf-8") if token else b""
    if not tok or b"\n" in tok:
        return None
    hits = 0
    line = 0            # newlines before the current block
    with open(path, "rb") as fh:
        carry = b""     # the unfinished last line of the previous block
        while True:
            data = fh.read(_BLOCK_BYTES)
            block = carry + data
            if not block:
                return None
            cut = len(block) if not data else block.rfind(b"\n") + 1
            if cut == 0:        # a line longer than the block: read on
                carry = block
                continue
            body = block[:cut]
            start = body.find(b"\n") + 1 if line == 0 else 0  # not in the header
            pos = body.find(tok, start)
            while pos >= 0:
                hits += 1
                if hits > _MAX_TOKEN_HITS:
                    return None
                end = pos + len(tok)
                if (pos == 0 or body[pos - 1] in _CELL_EDGE) and (end == len(body) or body[end] in _CELL_EDGE):
                    first = body.rfind(b"\n", 0, pos) + 1
                    last = body.find(b"\n", pos)
                    n = line + body.count(b"\n", 0, first)
                    return n - 1, body[first:last if last >= 0 else len(body)].rstrip(b"\r")
                pos = body.find(tok, pos + 1)
            line += body.count(b"\n")
            carry = block[cut:]
            if not data:
                return None


def _locate_bad_cell(path: Path, names: dict[str, str], numeric: list[str],
                     exc: Exception | None = None) -> SessionFormatError:
    """Find the first non-numeric or non-finite numeric cell and describe it.

    Reads the numeric columns again as floats in blocks of :data:`_LOCATE_CHUNK_ROWS` rows (as
    fast as the first read, memory bounded by one block) and only the block that fails as text,
    so a bad cell at the end of a 5-million-row file costs about one more read of the file, not
    a text copy of all of it (issue 12). Before that, when pandas' message quotes the text it
    could not convert (``exc``), one scan for that text finds the row in a second or two.
    """
    import re

    import pandas as pd

    header = _header(path)
    m = re.fullmatch(r"could not convert string to float: '(.*)'", str(exc)) if exc is not None else None
    if m is not None:
        hit = _find_token_row(path, m.group(1))
        found = _bad_row_text(path, header, names, numeric, *hit) if hit is not None else None
        if found is not None:
            return found
    cols = [names[c] for c in numeric]
    reader = pd.read_csv(path, usecols=cols, dtype={c: "float64" for c in cols}, chunksize=_LOCATE_CHUNK_ROWS,
                         skip_blank_lines=False, encoding="utf-8-sig", engine="c")
    first = 0
    with reader:
        while True:
            try:
                chunk = next(reader)
            except StopIteration:
                break
            except ValueError:
                found = _first_bad_text(path, header, names, numeric, first, _LOCATE_CHUNK_ROWS)
                if found is not None:
                    return found
                break
            finite = np.isfinite(chunk[cols].to_numpy(dtype=float))
            if not finite.all():
                i = int(np.argmax(~finite.all(axis=1)))
                found = _bad_row_text(path, header, names, numeric, first + i)
                if found is not None:
                    return found
            first += len(chunk)
    return SessionFormatError(f"{path}: unreadable numeric data")


def _check_plausible(path: Path, columns: list[str], m: np.ndarray) -> None:
    """Refuse finite but absurd values (:data:`PLAUSIBLE_ABS`), naming the first row and column."""
    limits = np.array([PLAUSIBLE_ABS.get(c, np.inf) for c in columns])
    if np.isinf(limits).all():
        return
    out = m > limits          # two boolean masks, not a float copy of a 5 M-row file (np.abs)
    out |= m < -limits
    rows = out.any(axis=1)
    if not rows.any():
        return
    i = int(np.argmax(rows))
    j = int(np.argmax(out[i]))
    c = columns[j]
    raise SessionFormatError(f"{path}: row {_row(i)}, column {c}: {float(m[i, j]):g} is not a plausible "
                             f"value (|{c}| <= {limits[j]:g})")


def _read_numeric(path: Path, required: list[str], *, min_rows: int = 1) -> np.ndarray:
    """Read the required float columns of a CSV; strict checks per FORMATS.md.

    Returns
    -------
    (n, len(required)) float array, columns in the order of ``required``: a read-only view of
    the parsed data. Not copied on purpose: the copy (and its page faults) cost more than the
    parsing of a 3-million-row IMU file; read-only also means no step downstream can change the
    raw recorded data by accident.
    """
    import pandas as pd

    header = _header(path)
    names = _require(path, header, required)
    try:
        # no usecols: with it pandas silently accepts rows with too many fields
        df = pd.read_csv(path, dtype={names[c]: "float64" for c in required},
                         skip_blank_lines=False, encoding="utf-8-sig", engine="c")
    except UnicodeDecodeError:   # a ValueError too: catch it first
        raise _utf8_error(path) from None
    except ValueError as exc:
        if isinstance(exc, pd.errors.ParserError):
            raise _parser_error(path, exc) from None
        raise _locate_bad_cell(path, names, required, exc) from None
    _check_no_implicit_index(path, df)
    if len(df) < min_rows:
        raise SessionFormatError(f"{path}: {len(df)} data row(s), at least {min_rows} needed"
                                 if len(df) else f"{path}: row 2: no data rows")
    # one float block: a view, its rows being the file's rows
    m = df[[names[c] for c in required]].to_numpy(dtype=float)
    m.flags.writeable = False
    finite = np.isfinite(m)
    if not finite.all():
        i = int(np.argmax(~finite.all(axis=1)))
        raise _bad_row_text(path, header, names, required, i) or _locate_bad_cell(path, names, required)
    _check_plausible(path, required, m)
    _check_time(path, m[:, required.index("t_s")])
    return m


def _check_time(path: Path, t: np.ndarray, rows: np.ndarray | None = None) -> None:
    """Refuse time going backwards; ``rows``: the file's data row of each value (blank lines left out)."""
    back = np.diff(t) < 0
    if np.any(back):
        i = int(np.argmax(back)) + 1
        row = _row(i if rows is None else int(rows[i]))
        raise SessionFormatError(f"{path}: row {row}, column t_s: time goes backwards "
                                 f"({float(t[i])!r} after {float(t[i - 1])!r})")


def _read_fixes(path: Path, default_sigma: float) -> Fixes:
    import pandas as pd

    header = _header(path)
    names = _require(path, header, FIXES_COLUMNS)
    sig = [c for c in FIXES_SIGMA_COLUMNS if c in names]
    covs = [c for c in FIXES_COV_COLUMNS if c in names]
    use = FIXES_COLUMNS + sig + covs
    try:
        # small file: read as text (keeps point labels such as "NA") and convert per column
        raw = pd.read_csv(path, dtype=str,
                          keep_default_na=False, skip_blank_lines=False, encoding="utf-8-sig",
                          engine="c")
    except UnicodeDecodeError:
        raise _utf8_error(path) from None
    except pd.errors.ParserError as exc:
        raise _parser_error(path, exc) from None
    _check_no_implicit_index(path, raw)
    # blank lines (a spreadsheet's trailing empty rows) are no fixes; rows keep their file numbers
    blank = (raw.apply(lambda col: col.str.strip()) == "").all(axis=1).to_numpy()
    file_rows = np.flatnonzero(~blank)
    raw = raw[~blank].reset_index(drop=True)
    n = len(raw)
    if n < 1:
        raise SessionFormatError(f"{path}: row 2: no data rows")
    num = ["t_s", "E_m", "N_m", "H_m"]
    vals = {}
    for c in num + sig + covs:
        s = raw[names[c]].str.strip()
        v = pd.to_numeric(s, errors="coerce").to_numpy(dtype=float, copy=True)
        if c in sig:  # an empty sigma cell means "the default"
            v[(s == "").to_numpy()] = default_sigma
        if c in covs:  # and an empty covariance cell "uncorrelated"
            v[(s == "").to_numpy()] = 0.0
        vals[c] = v
    first = None
    for c in num + sig + covs:
        bad = ~np.isfinite(vals[c]) | (np.abs(vals[c]) > PLAUSIBLE_ABS.get(c, np.inf))
        if c in sig:
            bad |= ~((vals[c] >= SIGMA_RANGE_M[0]) & (vals[c] <= SIGMA_RANGE_M[1]))
        if np.any(bad):
            i = int(np.argmax(bad))
            if first is None or i < first[0]:
                first = (i, c)
    points = raw[names["point"]].to_numpy(dtype=object).copy()
    empty = np.array([str(p).strip() == "" for p in points], dtype=bool)
    if np.any(empty) and (first is None or int(np.argmax(empty)) < first[0]):
        first = (int(np.argmax(empty)), "point")
    if first is not None:
        i, c = first
        value = raw[names[c]].iloc[i]
        what = ("empty point label" if c == "point" else
                f"sigma must be a positive number from {SIGMA_RANGE_M[0]:g} to {SIGMA_RANGE_M[1]:g} m"
                if c in sig and value.strip() != "" and
                np.isfinite(pd.to_numeric(value.strip(), errors="coerce")) else
                f"{value.strip()} is not a plausible value (|{c}| <= {PLAUSIBLE_ABS[c]:g})"
                if c in PLAUSIBLE_ABS and np.isfinite(pd.to_numeric(value.strip(), errors="coerce")) else
                _cell_problem(value))
        raise SessionFormatError(f"{path}: row {_row(int(file_rows[i]))}, column {c}: {what}")
    t = vals["t_s"]
    _check_time(path, t, rows=file_rows)
    sigma = np.full((n, 3), float(default_sigma))
    for j, c in enumerate(FIXES_SIGMA_COLUMNS):
        if c in vals:
            sigma[:, j] = vals[c]
    cov = None
    if covs:
        cov = np.column_stack([vals.get(c, np.zeros(n)) for c in FIXES_COV_COLUMNS])
        _check_fix_covariances(path, file_rows, sigma, cov)
    points = np.array([str(p).strip() for p in points], dtype=object)
    return Fixes(t_s=t, point=points,
                 enh_m=np.column_stack([vals["E_m"], vals["N_m"], vals["H_m"]]),
                 sigma_m=sigma, cov_m2=cov)


def _check_fix_covariances(path: Path, file_rows: np.ndarray, sigma: np.ndarray, cov: np.ndarray) -> None:
    """Each fix's covariance must be one: positive semi-definite with its sigmas (every
    correlation within +-1, and the three together consistent). The first row that is not is
    named with the column that breaks it."""
    fx = Fixes(np.zeros(len(sigma)), np.zeros(len(sigma), dtype=object), np.zeros((len(sigma), 3)), sigma, cov)
    c = fx.covariance_enh_m2()
    d = np.sqrt(np.diagonal(c, axis1=1, axis2=2))
    corr = c / (d[:, :, None] * d[:, None, :])
    rho = np.column_stack([corr[:, 0, 1], corr[:, 0, 2], corr[:, 1, 2]])
    # a correlation matrix is PSD when its smallest eigenvalue is >= 0 (to rounding)
    bad = np.linalg.eigvalsh(corr)[:, 0] < -1e-9
    if not np.any(bad):
        return
    i = int(np.argmax(bad))
    j = int(np.argmax(np.abs(rho[i])))
    pair = ("sigma_E_m and sigma_N_m", "sigma_E_m and sigma_H_m", "sigma_N_m and sigma_H_m")[j]
    raise SessionFormatError(f"{path}: row {_row(int(file_rows[i]))}, column {FIXES_COV_COLUMNS[j]}: with {pair} "
                             f"it is no covariance (correlation {rho[i, j]:+.3f}; the three correlations "
                             f"{', '.join(f'{r:+.3f}' for r in rho[i])} must make a positive semi-definite matrix)")


def read_session(folder: Path) -> RawSession:
    """Read and validate a raw session folder (FORMATS.md sec. 1).

    Parameters
    ----------
    folder : Path of the session folder.

    Returns
    -------
    RawSession
        Arrays in SI units; the sensor arrays are read-only views of the parsed files (raw
        data is never changed downstream; copy before changing).

    Raises
    ------
    SessionFormatError
        The first problem found, naming the file, the row (header = row 1) and the column.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SessionFormatError(f"{folder}: not a session folder (no such directory)")
    meta = read_session_meta(folder)
    imu = _read_numeric(folder / "imu.csv", IMU_COLUMNS, min_rows=2)
    odo = _read_numeric(folder / "odometer.csv", ODOMETER_COLUMNS, min_rows=2)
    fixes = _read_fixes(folder / "fixes.csv", meta.fix_sigma_m)
    gauge_t = gauge = None
    # (an empty gauge.csv, 0 bytes, is a session without gauge readings, as a header-only one is)
    if (folder / "gauge.csv").exists() and not ((folder / "gauge.csv").is_file()
                                               and (folder / "gauge.csv").stat().st_size == 0):
        g = _read_numeric(folder / "gauge.csv", GAUGE_COLUMNS, min_rows=0)
        gauge_t, gauge = g[:, 0], g[:, 1]
    _check_coverage(folder, imu[:, 0], odo[:, 0], odo[:, 1], fixes.t_s)
    if meta.crs and not math.isfinite(meta.latitude_rad):
        from trolley.projection import CrsError, session_site
        try:
            meta, _ = session_site(meta, fixes.enh_m)
        except CrsError as exc:
            raise SessionFormatError(f"{folder / 'session.toml'}: key site.crs: {exc} (site placed at the fixes' "
                                     "centroid)") from None
    return RawSession(
        meta=meta, imu_t_s=imu[:, 0], imu_w_rad_s=imu[:, 1:4], imu_f_m_s2=imu[:, 4:7],
        odo_t_s=odo[:, 0], odo_distance_m=odo[:, 1], fixes=fixes,
        gauge_t_s=gauge_t, gauge_m=gauge,
    )


#: Fastest a trolley moves, m/s: an odometer step faster than this is a wrong value or a wrong unit
#: (distances in mm read as m are 1000 times a walking pace)
MAX_TROLLEY_SPEED_M_S = 30.0
#: Longest gap in the IMU log the dead reckoning is asked to bridge, s
MAX_IMU_GAP_S = 2.0
#: How far the odometer or the fixes may run past the IMU log's end (or start before it), s
TIME_SPAN_SLACK_S = 2.0


def _check_coverage(folder: Path, imu_t: np.ndarray, odo_t: np.ndarray, odo_d: np.ndarray,
                    fix_t: np.ndarray) -> None:
    """The files must describe one survey: no impossible odometer speed, no long hole in the IMU
    log, and the odometer and the fixes within the IMU's time span. Each file is valid on its own
    when this runs; without these checks one wrong distance made a 2 GB track of nonsense and a
    truncated imu.csv a short track whose later fixes were "rejected" for a reason that hid the cause.
    """
    dt, dd = np.diff(odo_t), np.diff(odo_d)
    with np.errstate(divide="ignore", invalid="ignore"):
        fast = (np.abs(dd) > MAX_TROLLEY_SPEED_M_S * dt) & ((dt > 0) | (dd != 0))
    if fast.any():
        i = int(np.argmax(fast)) + 1
        raise SessionFormatError(
            f"{folder / 'odometer.csv'}: row {_row(i)}, column distance_m: moves {dd[i - 1]:+.6g} m in "
            f"{dt[i - 1]:.6g} s (faster than {MAX_TROLLEY_SPEED_M_S:g} m/s, the fastest a trolley moves): a wrong "
            "value, or distances in mm?")
    gaps = np.diff(imu_t)
    if gaps.size and gaps.max() > MAX_IMU_GAP_S:
        i = int(np.argmax(gaps)) + 1
        raise SessionFormatError(
            f"{folder / 'imu.csv'}: row {_row(i)}, column t_s: no IMU samples for {gaps[i - 1]:.6g} s (from t = "
            f"{imu_t[i - 1]:.6g} s): the dead reckoning cannot bridge a gap of more than {MAX_IMU_GAP_S:g} s in the IMU log")
    lo, hi = imu_t[0] - TIME_SPAN_SLACK_S, imu_t[-1] + TIME_SPAN_SLACK_S
    for name, t in (("fixes.csv", fix_t), ("odometer.csv", odo_t)):
        outside = (t < lo) | (t > hi)
        if outside.any():
            i = int(np.argmax(outside))
            raise SessionFormatError(
                f"{folder / name}: row {_row(i)}, column t_s: {t[i]:.6g} s is outside the IMU log ({imu_t[0]:.6g} to "
                f"{imu_t[-1]:.6g} s): imu.csv cut short, or the files of two sessions?")


def read_design(folder: Path, meta: SessionMeta, notes: list[str] | None = None):
    """The design alignment named by ``[design] alignment`` (and ``[design] name`` in a file that
    holds several), or None. The reader's notes (skipped or tolerated elements) are appended to
    ``notes`` when it is given, each prefixed with the file name.

    Returns
    -------
    trolley.alignment.Alignment or None

    Raises
    ------
    SessionFormatError
        The file is missing or is not a valid LandXML alignment.
    """
    if meta.design_alignment is None:
        return None
    from trolley.landxml import LandXmlError, decoded_landxml, read_landxml

    path = Path(folder) / meta.design_alignment
    try:
        text = decoded_landxml(path.read_bytes())
    except FileNotFoundError:
        raise SessionFormatError(f"{Path(folder) / 'session.toml'}: key design.alignment: file "
                                 f"{meta.design_alignment!r} not found in {folder}") from None
    except LandXmlError as exc:
        raise SessionFormatError(f"{path}: {exc}") from None
    try:
        design = read_landxml(text, meta.design_alignment_name)
    except ValueError as exc:
        raise SessionFormatError(f"{path}: {exc}") from None
    if notes is not None:
        notes.extend(f"{meta.design_alignment}: {n}" for n in design.notes)
    return design.alignment


# ------------------------------------------------------------------------------------------
# writing
# ------------------------------------------------------------------------------------------
def _csv_label(s: str) -> str:
    s = str(s)
    if any(ch in s for ch in ',"\r\n') or s != s.strip():
        return '"' + s.replace('"', '""') + '"'
    return s


def write_csv_columns(path: Path, header: list[str], columns: list, formats: list[str],
                      chunk: int = 100_000, nan_as_empty: bool = False) -> None:
    """Write columns with per-column %-formats (fast: one % per row, chunked).

    ``nan_as_empty`` writes NaN as an empty cell (what pandas' ``na_rep=""`` does); only for
    all-numeric formats, where "nan" can be nothing but a formatted NaN.
    """
    fmt = ",".join(formats)
    if nan_as_empty and "%s" in fmt:
        raise ValueError("nan_as_empty needs numeric formats only")
    n = len(columns[0]) if columns else 0
    with open(path, "w", encoding="utf-8", newline="") as fh:
        fh.write(",".join(header) + "\n")
        for i0 in range(0, n, chunk):
            i1 = min(i0 + chunk, n)
            cols = [c[i0:i1].tolist() if isinstance(c, np.ndarray) else list(c[i0:i1])
                    for c in columns]
            text = "\n".join(map(fmt.__mod__, zip(*cols)))
            fh.write(text.replace("nan", "") if nan_as_empty else text)
            fh.write("\n")


def _check_finite(name: str, col: str, x: np.ndarray) -> None:
    bad = ~np.isfinite(np.asarray(x, dtype=float))
    if np.any(bad):
        raise ValueError(f"{name}: refusing to write non-finite {col} at data row "
                         f"{_row(int(np.argmax(bad)))}")


def _write_session_files(tmp: Path, session: RawSession, design_xml: str | None,
                         exact: bool, progress: Callable[[str, float], None] | None = None) -> None:
    meta = session.meta
    if progress is not None:
        progress("writing imu.csv", 0.0)
    sensor = _EXACT if exact else _SENSOR
    (tmp / "session.toml").write_text(session_toml_text(meta), encoding="utf-8")
    w = np.asarray(session.imu_w_rad_s, dtype=float)
    f = np.asarray(session.imu_f_m_s2, dtype=float)
    t = np.asarray(session.imu_t_s, dtype=float)
    if w.shape != (t.size, 3) or f.shape != (t.size, 3):
        raise ValueError("imu arrays must be (N,), (N, 3), (N, 3)")
    for col, x in zip(IMU_COLUMNS, [t, *w.T, *f.T]):
        _check_finite("imu.csv", col, x)
    write_csv_columns(tmp / "imu.csv", IMU_COLUMNS, [t, *w.T, *f.T], [_EXACT] + [sensor] * 6)
    if progress is not None:
        # imu.csv is most of the bytes: the other files share the last fifth
        progress("writing odometer.csv, fixes.csv, gauge.csv", 0.8)
    _check_finite("odometer.csv", "t_s", session.odo_t_s)
    _check_finite("odometer.csv", "distance_m", session.odo_distance_m)
    write_csv_columns(tmp / "odometer.csv", ODOMETER_COLUMNS,
               [np.asarray(session.odo_t_s, float), np.asarray(session.odo_distance_m, float)],
               [_EXACT, _EXACT])
    fx = session.fixes
    enh = np.asarray(fx.enh_m, dtype=float)
    sig = np.asarray(fx.sigma_m, dtype=float)
    cov_cols, cov = ([], []) if fx.cov_m2 is None else (FIXES_COV_COLUMNS, list(np.asarray(fx.cov_m2, dtype=float).T))
    for col, x in zip(["t_s", "E_m", "N_m", "H_m"] + FIXES_SIGMA_COLUMNS + cov_cols,
                      [fx.t_s, *enh.T, *sig.T, *cov]):
        _check_finite("fixes.csv", col, x)
    labels = [_csv_label(p) for p in fx.point]
    write_csv_columns(tmp / "fixes.csv", FIXES_COLUMNS + FIXES_SIGMA_COLUMNS + cov_cols,
               [np.asarray(fx.t_s, float), labels, *enh.T, *sig.T, *cov],
               [_EXACT, "%s"] + [_EXACT] * (6 + len(cov_cols)))
    if session.gauge_t_s is not None:
        _check_finite("gauge.csv", "t_s", session.gauge_t_s)
        _check_finite("gauge.csv", "gauge_m", session.gauge_m)
        write_csv_columns(tmp / "gauge.csv", GAUGE_COLUMNS,
                   [np.asarray(session.gauge_t_s, float), np.asarray(session.gauge_m, float)],
                   [_EXACT, _EXACT])
    if meta.design_alignment is not None:
        if design_xml is None:
            raise ValueError(f"session.toml names the design {meta.design_alignment!r} but no "
                             f"design_xml text was given")
        target = tmp / meta.design_alignment
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(design_xml, encoding="utf-8")


def write_session(folder: Path, session: RawSession, design_xml: str | None = None, *,
                  overwrite: bool = False, exact: bool = False,
                  extra_files: Mapping[str, Callable[[Path], None]] | None = None,
                  progress: Callable[[str, float], None] | None = None) -> None:
    """Write a raw session folder atomically (FORMATS.md sec. 1).

    Parameters
    ----------
    folder : target folder; it must not exist (or be empty) unless ``overwrite``.
    session : the session. If ``session.meta.design_alignment`` is set, ``design_xml`` must
        hold the LandXML text, written under that name; if it is None and ``design_xml`` is
        given, the design is written as ``alignment.xml`` and named in session.toml.
    design_xml : LandXML text of the design, or None.
    overwrite : replace an existing folder (the old one is removed only after the new one is
        in place).
    exact : write the IMU samples with the shortest exact repr too (bigger, slower files).
    extra_files : name -> writer(path) of further files to put into the folder before it is
        renamed into place (e.g. ``truth.csv``), so that the folder appears complete or not
        at all.
    progress : optional callable ``progress(step, fraction)``, called as each file begins.

    Raises
    ------
    FileExistsError
        ``folder`` exists, is not empty and ``overwrite`` is False.
    ValueError
        Non-finite data, inconsistent shapes, or a design named without its text.
    """
    from dataclasses import replace

    folder = Path(folder)
    if session.meta.design_alignment is None and design_xml is not None:
        session = replace(session, meta=replace(session.meta, design_alignment="alignment.xml"))
    if folder.exists() and not overwrite and (not folder.is_dir() or any(folder.iterdir())):
        raise FileExistsError(f"{folder}: already exists and is not empty")
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".partial", dir=folder.parent))
    try:
        os.chmod(tmp, folder_mode())
        _write_session_files(tmp, session, design_xml, exact, progress)
        for name, writer in (extra_files or {}).items():
            if progress is not None:
                progress(f"writing {name}", 0.95)
            writer(tmp / name)
        move_into_place(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def move_into_place(tmp: Path, folder: Path) -> None:
    """Put the complete folder ``tmp`` in the place of ``folder`` (absent, empty or not): the old
    one is renamed aside just before and deleted just after; if the second rename fails the first
    is undone (POSIX has no portable exchange of two folders), so ``folder`` is always either the
    old one or the new one, never a mix. A ``folder`` that is a symbolic link is replaced as a
    link: the new folder takes its name, the folder it pointed to is left untouched."""
    if not folder.exists():
        os.rename(tmp, folder)
        return
    if folder.is_dir() and not any(folder.iterdir()):
        folder.rmdir()
        os.rename(tmp, folder)
        return
    old = folder.with_name(f".{folder.name}.old-{os.getpid()}")
    os.rename(folder, old)
    try:
        os.rename(tmp, folder)
    except BaseException:
        os.rename(old, folder)
        raise
    if old.is_symlink() or not old.is_dir():
        # a link is removed, never followed: the folder it pointed to stays as it was
        old.unlink()
    else:
        shutil.rmtree(old, ignore_errors=True)


# ------------------------------------------------------------------------------------------
# truth.csv
# ------------------------------------------------------------------------------------------
def write_truth_csv(path: Path, truth, step_m: float = 0.1) -> None:
    """Write the truth every ``step_m`` of chainage (atomic).

    Columns: chainage_m, E_m, N_m, H_m (track reference point), roll_rad, pitch_rad, yaw_rad
    (trolley, NED), gauge_m, cant_mm (rail_spacing * sin(roll)), lateral_mm and vertical_mm
    (true offset from the design, + right / + up).

    Parameters
    ----------
    path : output file.
    truth : trolley.truthsim.TruthTrack (with its geometry).
    step_m : chainage step, m.
    """
    path = Path(path)
    p = truth.resampled(step_m)
    cols = [p.chainage_m, p.E_m, p.N_m, p.H_m, p.roll_rad, p.pitch_rad, p.yaw_rad, p.gauge_m,
            units.m_to_mm(p.cant_m), units.m_to_mm(p.lateral_m), units.m_to_mm(p.vertical_m)]
    write_with(path, lambda tmp: write_csv_columns(tmp, TRUTH_COLUMNS, cols, [_EXACT] * len(cols)))


def read_truth_csv(path: Path):
    """Read a ``truth.csv`` back into a :class:`trolley.truthsim.TruthProfile` (SI units)."""
    from trolley.truthsim import TruthProfile

    path = Path(path)
    cols = _read_numeric_generic(path, TRUTH_COLUMNS)
    return TruthProfile(chainage_m=cols["chainage_m"], E_m=cols["E_m"], N_m=cols["N_m"],
                        H_m=cols["H_m"], roll_rad=cols["roll_rad"], pitch_rad=cols["pitch_rad"],
                        yaw_rad=cols["yaw_rad"], gauge_m=cols["gauge_m"],
                        cant_m=units.mm_to_m(cols["cant_mm"]),
                        lateral_m=units.mm_to_m(cols["lateral_mm"]),
                        vertical_m=units.mm_to_m(cols["vertical_mm"]))


def _read_numeric_generic(path: Path, required: list[str]) -> dict[str, np.ndarray]:
    import pandas as pd

    header = _header(path)
    names = _require(path, header, required)
    try:
        df = pd.read_csv(path, usecols=[names[c] for c in required],
                         dtype={names[c]: "float64" for c in required},
                         skip_blank_lines=False, encoding="utf-8-sig", engine="c")
    except UnicodeDecodeError:
        raise _utf8_error(path) from None
    except ValueError:
        raise _locate_bad_cell(path, names, required) from None
    _check_no_implicit_index(path, df)
    out = {c: df[names[c]].to_numpy(dtype=float, copy=True) for c in required}
    if any(not np.all(np.isfinite(v)) for v in out.values()):
        raise _locate_bad_cell(path, names, required)
    _check_plausible(path, required, np.column_stack([out[c] for c in required]))
    return out
