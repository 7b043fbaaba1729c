"""Tolerance sets for track geometry and the defects (exceedances) they flag.

A tolerance set is data, a TOML text (format ``trolley-tolerances/1``, described in
docs/track_geometry.md), parsed here from a string; reading the file is the survey layer's job.
Limits are written in the units of the standards (mm, mm/m) and converted to SI once, here.
Every limit carries its source, or is marked ``example = true``.

An exceedance is a station whose value lies outside [lower, upper]; consecutive exceeding
stations of one parameter form one defect (chainage from-to, peak value, limit violated).

References
----------
EN 13848-5 (isolated defects, alert / intervention / immediate-action limits); TB 10754
(ballastless track static acceptance); shared/research/anchors.md 2.1-2.2.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from trolley import units

FORMAT = "trolley-tolerances/1"

# field suffix in the TOML -> (column suffix, converter to SI)
_UNITS = {
    "mm": ("_m", units.mm_to_m),
    "mm_per_m": ("_m_per_m", units.mm_per_m_to_ratio),
}
_GEOMETRY_KEYS = ("twist_base_m", "gauge_rate_base_m", "versine_chord_m")


@dataclass(frozen=True)
class Limit:
    """One limit on one parameter (SI).

    Attributes
    ----------
    parameter : key in the tolerance file, e.g. ``gauge_dev``.
    column : geometry column it applies to, e.g. ``gauge_dev_m``.
    lower, upper : allowed range, SI (-inf / +inf when open).
    unit : display unit of the file ("mm" or "mm_per_m").
    source : where the value comes from ("" when only an example).
    example : True when the value is an example, not taken from a cited source.
    note : free text.
    """

    parameter: str
    column: str
    lower: float
    upper: float
    unit: str
    source: str = ""
    example: bool = False
    note: str = ""


@dataclass(frozen=True)
class ToleranceSet:
    """A named set of limits.

    Attributes
    ----------
    name, title, description : identification.
    limits : the limits, in file order.
    twist_base_m, gauge_rate_base_m, versine_chord_m : bases the limits refer to (None when
        the file does not say).
    origin : file or resource it was read from (for messages).
    """

    name: str
    title: str
    description: str
    limits: tuple[Limit, ...]
    twist_base_m: float | None = None
    gauge_rate_base_m: float | None = None
    versine_chord_m: float | None = None
    origin: str = ""


@dataclass(frozen=True)
class Defect:
    """Consecutive stations of one parameter outside its limit.

    Attributes
    ----------
    parameter, column : as in :class:`Limit`.
    start_chainage_m, end_chainage_m : first and last exceeding station, m.
    peak : value with the largest exceedance (SI, signed).
    limit : the bound it violates (SI).
    stations : number of exceeding stations.
    """

    parameter: str
    column: str
    start_chainage_m: float
    end_chainage_m: float
    peak: float
    limit: float
    stations: int


class ToleranceError(ValueError):
    """A tolerance file that cannot be used; the message names the file and the key."""


def _number(origin: str, where: str, v) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise ToleranceError(f"{origin}: {where} must be a finite number, got {v!r}")
    return float(v)


def parse_tolerances(text: str, origin: str = "<string>") -> ToleranceSet:
    """Parse a tolerance set from TOML text.

    Parameters
    ----------
    text : TOML (format ``trolley-tolerances/1``).
    origin : file name for error messages.

    Returns
    -------
    ToleranceSet

    Raises
    ------
    ToleranceError
        Invalid TOML, wrong format, a limit without a bound, a unit other than mm or mm_per_m,
        or a limit with neither ``source`` nor ``example = true``.
    """
    try:
        doc = tomllib.loads(text.removeprefix("\ufeff"))   # (a BOM, as Notepad writes)
    except tomllib.TOMLDecodeError as e:
        raise ToleranceError(f"{origin}: not valid TOML: {e}") from None
    if doc.get("format") != FORMAT:
        raise ToleranceError(f"{origin}: format must be {FORMAT!r}, got {doc.get('format')!r}")
    geo = doc.get("geometry", {})
    if not isinstance(geo, dict):
        raise ToleranceError(f"{origin}: [geometry] must be a table")
    bases = {}
    for k, v in geo.items():
        if k not in _GEOMETRY_KEYS:
            raise ToleranceError(f"{origin}: [geometry] {k}: unknown key (known: {', '.join(_GEOMETRY_KEYS)})")
        bases[k] = _number(origin, f"[geometry] {k}", v)
        if bases[k] <= 0:
            raise ToleranceError(f"{origin}: [geometry] {k} must be > 0")
    raw = doc.get("limits")
    if not isinstance(raw, dict) or not raw:
        raise ToleranceError(f"{origin}: no [limits.<parameter>] tables")
    limits = []
    for key, spec in raw.items():
        where = f"[limits.{key}]"
        if not isinstance(spec, dict):
            raise ToleranceError(f"{origin}: {where} must be a table")
        found = None
        for unit, (suffix, to_si) in _UNITS.items():
            fields = {f: spec[f"{f}_{unit}"] for f in ("min", "max", "max_abs") if f"{f}_{unit}" in spec}
            if fields:
                if found is not None:
                    raise ToleranceError(f"{origin}: {where} mixes units")
                found = (unit, suffix, to_si, fields)
        if found is None:
            raise ToleranceError(f"{origin}: {where} needs min_<unit>, max_<unit> or max_abs_<unit> "
                                 f"with unit one of {', '.join(_UNITS)}")
        unit, suffix, to_si, fields = found
        vals = {f: to_si(_number(origin, f"{where} {f}_{unit}", v)) for f, v in fields.items()}
        if "max_abs" in vals:
            if "min" in vals or "max" in vals:
                raise ToleranceError(f"{origin}: {where} gives max_abs together with min/max")
            if vals["max_abs"] < 0:
                raise ToleranceError(f"{origin}: {where} max_abs must be >= 0")
            lower, upper = -vals["max_abs"], vals["max_abs"]
        else:
            lower, upper = vals.get("min", -np.inf), vals.get("max", np.inf)
            if lower > upper:
                raise ToleranceError(f"{origin}: {where} min > max")
        source = spec.get("source", "")
        example = spec.get("example", False)
        if not isinstance(source, str) or not isinstance(example, bool):
            raise ToleranceError(f"{origin}: {where} source must be text and example true/false")
        if not source and not example:
            raise ToleranceError(f"{origin}: {where} needs a source or example = true")
        known = {f"{f}_{unit}" for f in ("min", "max", "max_abs")} | {"source", "example", "note"}
        extra = sorted(set(spec) - known)
        if extra:
            raise ToleranceError(f"{origin}: {where} unknown keys: {', '.join(extra)}")
        limits.append(Limit(parameter=key, column=key + suffix, lower=float(lower), upper=float(upper),
                            unit=unit, source=source, example=example, note=str(spec.get("note", ""))))
    return ToleranceSet(name=str(doc.get("name", origin)), title=str(doc.get("title", "")),
                        description=str(doc.get("description", "")), limits=tuple(limits),
                        origin=origin, **bases)


def exceedance(values: np.ndarray, limit: Limit) -> np.ndarray:
    """Boolean mask of the stations outside ``limit`` (NaN never exceeds)."""
    v = np.asarray(values, dtype=float)
    with np.errstate(invalid="ignore"):
        return (v < limit.lower) | (v > limit.upper)


def find_defects(chainage_m: np.ndarray, columns: Mapping[str, np.ndarray],
                 tolerances: ToleranceSet) -> list[Defect]:
    """Defects: runs of consecutive stations outside a limit, one per run and parameter.

    Parameters
    ----------
    chainage_m : station chainage, m.
    columns : geometry column name -> values (SI), e.g. :attr:`TrackGeometry.columns`.
    tolerances : the limits; limits on columns not in ``columns`` raise.

    Returns
    -------
    defects : sorted by start chainage, then parameter.
    """
    s = np.asarray(chainage_m, dtype=float)
    out: list[Defect] = []
    for lim in tolerances.limits:
        if lim.column not in columns:
            # say it in the file's terms: the keys a limit may have, and the unit that key takes
            other = {c[:-len(suffix)]: u for c in columns for u, (suffix, _) in _UNITS.items()
                     if c.endswith(suffix) and not (u == "mm" and c.endswith("_m_per_m"))}
            unit_name = {"mm": "mm", "mm_per_m": "mm/m"}
            if lim.parameter in other:
                raise ToleranceError(f"{tolerances.origin}: [limits.{lim.parameter}]: {lim.parameter} is in "
                                     f"{unit_name[other[lim.parameter]]}, not {unit_name[lim.unit]}: use "
                                     f"min_{other[lim.parameter]} / max_{other[lim.parameter]} / "
                                     f"max_abs_{other[lim.parameter]}")
            raise ToleranceError(f"{tolerances.origin}: [limits.{lim.parameter}]: no such parameter (known: "
                                 f"{', '.join(sorted(other))})")
        v = np.asarray(columns[lim.column], dtype=float)
        mask = exceedance(v, lim)
        if not mask.any():
            continue
        edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
        starts = np.flatnonzero(edges == 1)
        stops = np.flatnonzero(edges == -1)          # exclusive
        excess = np.where(v > lim.upper, v - lim.upper, lim.lower - v)
        excess = np.where(mask, excess, -np.inf)
        # peak of each run: argmax of the excess within [start, stop)
        run = np.cumsum(edges[:-1] == 1) - 1
        idx = np.flatnonzero(mask)
        order = np.lexsort((-excess[idx], run[idx]))
        first = np.r_[True, np.diff(run[idx][order]) != 0]
        peaks = idx[order][first]
        for a, b, p in zip(starts, stops, peaks):
            out.append(Defect(parameter=lim.parameter, column=lim.column,
                              start_chainage_m=float(s[a]), end_chainage_m=float(s[b - 1]),
                              peak=float(v[p]), limit=float(lim.upper if v[p] > lim.upper else lim.lower),
                              stations=int(b - a)))
    out.sort(key=lambda d: (d.start_chainage_m, d.parameter))
    return out


__all__ = ["FORMAT", "Limit", "ToleranceSet", "Defect", "ToleranceError", "parse_tolerances",
           "exceedance", "find_defects"]
