"""CPIII control-point files: CSV ``id,E_m,N_m,H_m`` and Leica GSI-8 / GSI-16 coordinate blocks.

GSI (``shared/research/protocols.md`` section 2): one block per line, words of 16 characters
(GSI-8) or 24 (GSI-16, the line starts with ``*``), each ``WI`` (2 digits, or 3 for 5xx) + info
+ unit digit (position 6) + sign (position 7) + right-aligned data. A point is a block with word 11
(point id, leading zeros stripped) and words 81 / 82 / 83 (target E / N / H). Coordinates must be
in metres: unit digit 0 (last digit 1 mm), 6 (0.1 mm) or 8 (0.01 mm); feet (1, 7), angle units or
no unit digit are errors. Code blocks (word 41) and unknown words are skipped.

Any error (malformed line, bad number, wrong unit, duplicate id) raises :class:`CpiiiError` naming
the file and the line, and nothing is imported from that file: the file is parsed completely
before anything is stored, and the store adds all points in one transaction.
"""
from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trolley.numbertext import foreign_character, parse_number

from survey.store import ControlPoint, PointConflict, ProjectStore

#: GSI unit digit -> divisor turning the integer data into metres.
GSI_METRE_DIVISORS: dict[str, int] = {"0": 1000, "6": 10000, "8": 100000}
_GSI_UNIT_NAMES = {"1": "ft (1/1000 ft)", "7": "ft (1/10000 ft)", "2": "gon", "3": "decimal degrees",
                   "4": "DMS", "5": "mil", ".": "none"}
_COORD_WORDS = {"81": "E (Easting)", "82": "N (Northing)", "83": "H (Height)"}
_GSI_COLUMNS = {"81": "E_m", "82": "N_m", "83": "H_m"}
_CSV_COLUMNS = ("id", "E_m", "N_m", "H_m")
_GSI_START = re.compile(r"^\*?\d{2}[\d.]{4}[+-]")


class CpiiiError(ValueError):
    """A CPIII file cannot be imported; the message names the file and the line."""

    def __init__(self, file: str, line: int, message: str):
        super().__init__(f"{file}:{line}: {message}" if line else f"{file}: {message}")
        self.file = file
        self.line = line


@dataclass(frozen=True)
class CpiiiImport:
    """Outcome of importing one file into a project."""

    file: str
    read: int
    added: int

    @property
    def already_present(self) -> int:
        """Points already in the project with the same coordinates."""
        return self.read - self.added


def _check_duplicates(points: list[ControlPoint], name: str) -> None:
    first: dict[str, int] = {}
    for p in points:
        if p.point_id in first:
            raise CpiiiError(name, p.line, f"duplicate point id {p.point_id!r} (first on line {first[p.point_id]})")
        first[p.point_id] = p.line


def parse_cpiii_csv(text: str, name: str = "<csv>") -> list[ControlPoint]:
    """Control points from CSV text with the columns ``id,E_m,N_m,H_m`` (extra columns ignored).

    Raises
    ------
    CpiiiError : missing column, empty id, non-numeric or non-finite value, wrong field count,
        duplicate id, no points.
    """
    reader = csv.reader(io.StringIO(text))
    header = None
    points: list[ControlPoint] = []
    for row in reader:
        line = reader.line_num
        if not row or all(not c.strip() for c in row):
            continue
        if header is None:
            header = [c.strip() for c in row]
            missing = [c for c in _CSV_COLUMNS if c not in header]
            if missing:
                raise CpiiiError(name, line, f"missing column(s) {', '.join(missing)}; the header must contain "
                                             f"{','.join(_CSV_COLUMNS)}")
            index = {c: header.index(c) for c in _CSV_COLUMNS}
            continue
        if len(row) != len(header):
            raise CpiiiError(name, line, f"{len(row)} fields, the header has {len(header)}")
        pid = row[index["id"]].strip()
        if not pid:
            raise CpiiiError(name, line, "column id: empty point id")
        values = []
        for col in _CSV_COLUMNS[1:]:
            cell = row[index[col]].strip()
            try:
                v = parse_number(cell)
            except ValueError as exc:
                raise CpiiiError(name, line, f"column {col}: {exc}") from None
            if not math.isfinite(v):
                raise CpiiiError(name, line, f"column {col}: {cell!r} is not finite")
            _check_plausible(col, v, f"column {col}", name, line)
            values.append(v)
        points.append(ControlPoint(pid, *values, source=name, line=line))
    if header is None:
        raise CpiiiError(name, 0, "empty file")
    if not points:
        raise CpiiiError(name, 0, "no points")
    _check_duplicates(points, name)
    return points


def _gsi_words(body: str, wide: bool, name: str, line: int) -> list[tuple[str, str, str, str]]:
    """Split a GSI block into (WI, info, unit digit, signed data) words, checking their lengths."""
    size = 23 if wide else 15
    out = []
    for k, w in enumerate(body.split(), start=1):
        if len(w) != size:
            kind = "GSI-16: line starts with '*'" if wide else "GSI-8: line without '*'"
            raise CpiiiError(name, line, f"word {k} {w!r} has {len(w)} characters, expected {size} and a blank ({kind})")
        if not (w[:2].isascii() and w[:2].isdigit() and w[6] in "+-"):
            raise CpiiiError(name, line, f"word {k} {w!r} is not a GSI word (WI digits, then sign at position 7)")
        wi = w[:3] if (w[0] == "5" and w[2].isdigit()) else w[:2]
        out.append((wi, w[2:6], w[5], w[6:]))
    return out


def _check_plausible(column: str, value: float, where: str, name: str, line: int) -> None:
    """The limits every reader of grid coordinates applies (sessionio.PLAUSIBLE_ABS: |E|, |N| <= 1e8 m,
    |H| <= 1e5 m): a coordinate typed with extra digits is refused here, not when a session or
    the CRS meets it."""
    from survey.sessionio import PLAUSIBLE_ABS

    if abs(value) > PLAUSIBLE_ABS[column]:
        raise CpiiiError(name, line, f"{where}: {value:.10g} is not a plausible value (|{column}| <= "
                                     f"{PLAUSIBLE_ABS[column]:g})")


def _gsi_coordinate(wi: str, unit: str, data: str, name: str, line: int) -> float:
    what = _COORD_WORDS[wi]
    if unit not in GSI_METRE_DIVISORS:
        raise CpiiiError(name, line, f"word {wi} ({what}): unit digit {unit!r} = {_GSI_UNIT_NAMES.get(unit, 'unknown')}; "
                                     f"coordinates must be metres (unit digit 0, 6 or 8)")
    digits = data[1:]
    foreign = foreign_character(digits)
    if foreign is not None or not digits.isdigit():
        raise CpiiiError(name, line, f"word {wi} ({what}): data {data!r} is not a number"
                         + (f": {foreign}" if foreign else ""))
    value = int(digits) / GSI_METRE_DIVISORS[unit]
    value = -value if data[0] == "-" else value
    _check_plausible(_GSI_COLUMNS[wi], value, f"word {wi} ({what})", name, line)
    return value


def parse_cpiii_gsi(text: str, name: str = "<gsi>") -> list[ControlPoint]:
    """Control points from Leica GSI-8 / GSI-16 text (words 11, 81, 82, 83).

    Raises
    ------
    CpiiiError : malformed word, wrong word length, non-metre unit, non-numeric coordinate,
        a point block without 81/82/83, a repeated word in a block, duplicate id, no points.
    """
    points: list[ControlPoint] = []
    for line, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if not s:
            continue
        wide = s.startswith("*")
        words = _gsi_words(s[1:] if wide else s, wide, name, line)
        wis = [w[0] for w in words]
        if wis[0] == "41":  # code block
            continue
        if "11" not in wis:
            raise CpiiiError(name, line, "block has no point id (word 11)")
        for wi in ("11", "81", "82", "83"):
            if wis.count(wi) > 1:
                raise CpiiiError(name, line, f"word {wi} appears {wis.count(wi)} times")
        found = {w[0]: w for w in words}
        missing = [f"{wi} ({_COORD_WORDS[wi]})" for wi in ("81", "82", "83") if wi not in found]
        pid = found["11"][3][1:].lstrip("0") or "0"
        if missing:
            raise CpiiiError(name, line, f"point {pid!r} has no word {', '.join(missing)}")
        e, n, h = (_gsi_coordinate(wi, found[wi][2], found[wi][3], name, line) for wi in ("81", "82", "83"))
        points.append(ControlPoint(pid, e, n, h, source=name, line=line))
    if not points:
        raise CpiiiError(name, 0, "no points")
    _check_duplicates(points, name)
    return points


def parse_cpiii_text(text: str, name: str) -> list[ControlPoint]:
    """CSV or GSI, chosen by the file name's extension (.csv, .gsi), else by the first non-blank line."""
    suffix = Path(name).suffix.lower()
    if suffix == ".csv":
        return parse_cpiii_csv(text, name)
    if suffix.startswith(".gsi"):
        return parse_cpiii_gsi(text, name)
    first = next((ln.strip() for ln in text.splitlines() if ln.strip()), "")
    return parse_cpiii_gsi(text, name) if _GSI_START.match(first) else parse_cpiii_csv(text, name)


def read_cpiii_file(path: Path | str) -> list[ControlPoint]:
    """Control points of a CSV or GSI file (UTF-8; a byte-order mark is tolerated)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as e:
        raise CpiiiError(str(path), 0, f"not UTF-8 text ({e.reason} at byte {e.start})") from None
    except OSError as e:
        raise CpiiiError(str(path), 0, e.strerror or str(e)) from None
    return parse_cpiii_text(text, str(path))


def import_cpiii_file(store: ProjectStore, path: Path | str) -> CpiiiImport:
    """Read a CPIII file and add its points to the project in one transaction (all or nothing).

    Raises
    ------
    CpiiiError : the file is malformed, or a point conflicts with one already in the project.
    """
    points = read_cpiii_file(path)
    crs = store.settings().crs
    if crs:
        # every point must be in the project CRS's domain (else the site, `show` and every
        # session fail on it later, and no command takes a point out again)
        from trolley.projection import crs_info, outside_domain

        bad = outside_domain(crs, [p.e_m for p in points], [p.n_m for p in points])
        if bad.any():
            p = points[int(np.argmax(bad))]
            raise CpiiiError(str(path), p.line, f"point {p.point_id!r}: E {p.e_m:.3f} N {p.n_m:.3f} is outside the "
                                                f"domain of the project CRS {crs_info(crs).name}")
    try:
        added = store.add_cpiii_points(points)
    except PointConflict as e:
        raise CpiiiError(str(path), e.point.line, e.detail) from None
    return CpiiiImport(file=str(path), read=len(points), added=added)
