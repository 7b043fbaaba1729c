"""LandXML 1.2 design alignments: read ``<Alignment>`` into :class:`~trolley.alignment.Alignment`
and write one back.

What is read (schema LandXML-1.2.xsd; see ``docs/conventions.md``, "Design geometry"):

- ``<Units>``: ``<Metric>`` (metre, millimetre, centimetre, kilometre) or ``<Imperial>``
  (``foot`` = international foot 0.3048 m, ``USSurveyFoot`` = 1200/3937 m, ``inch``, ``mile``),
  converted to metres here; cant values are mm (inches in an imperial file). Several unit
  elements are read only when they agree (see :func:`_units`).
- A file may hold several ``<Alignment>``: one is chosen by name (:func:`alignment_names` lists
  them; :class:`AlignmentChoiceError` when the choice is missing or unknown).
- ``<CoordGeom>``: ``<Line>``, ``<Curve>`` (circular arc, Start/Center/End) and ``<Spiral>``
  with ``spiType="clothoid"``. Point text is "Northing Easting [Elevation]" (the elevation is
  ignored). Directions (``dir``, ``dirStart``, ...) are NOT trusted: every heading is recomputed
  from coordinates (Line: Start->End; Curve: the radius Center->Start and ``rot``; Spiral:
  Start->PI). Line and arc lengths and the arc radius come from the coordinates too; the
  clothoid takes ``length``, ``radiusStart``, ``radiusEnd`` (``INF`` = straight) and ``rot``.
  Each element starts at its own Start point and direction (no chaining: a direction break of
  2e-5 rad at one join does not move every later element); the gap and direction break at
  each join are reported above :data:`JOIN_TOLERANCE_M` / :data:`DIRECTION_TOLERANCE_RAD` and
  refused above :data:`GAP_REFUSE_M` / :data:`DIRECTION_REFUSE_RAD`. Elements shorter than
  :data:`ZERO_LENGTH_M` are skipped. A declared ``Alignment/@length`` that disagrees with the
  elements is reported; the elements are used.
- ``<StaEquation>``: the drawing stationing (:class:`~trolley.stationing.Stationing`), kept on
  the alignment; chainage inside stays the internal station (staStart + distance).
- ``<Profile>/<ProfAlign>`` (the first one): ``<PVI>`` and ``<ParaCurve length>`` ("station
  elevation"); ``<CircCurve length radius>`` is an exact circle of that radius tangent to both
  grades (crest or sag from the grades, whatever the sign of the radius); its ``length`` must
  agree with the circle's arc length within max(0.1 m, 1 %). Curves overlapping by less than
  :data:`PROFILE_OVERLAP_TOLERANCE_M` are accepted with a note.
- ``<Cant>/<CantStation>``: ``appliedCant`` (a rail height difference) is converted to the
  cant angle asin(appliedCant / rail_spacing); its sign follows ``curvature`` (``cw``, a
  right-hand curve, raises the left rail: positive), flipped when ``adverse="true"``. Ramps
  between stations are linear (``transitionType`` absent, ``linear`` or ``clothoid``). A cant
  station off the alignment is refused with its station.
- Cant and PVI stations are internal stations by the schema; with station equations, files
  that give them as drawing stations are recognised (their cant stations fall on element joins
  that way) and converted, with a note.

``<Feature>`` anywhere, vendor extensions (other namespaces) and other schema elements the
import does not use are skipped with a note. Anything else that changes the geometry (other
spiral types, ``UnsymParaCurve``, ``IrregularLine``, ``Chain``, point references) is refused
with :class:`LandXmlError` naming the element.

References
----------
LandXML-1.2 schema, http://www.landxml.org/schema/LandXML-1.2/LandXML-1.2.xsd (Alignment,
Spiral, Curve, Profile, Cant, CantStation, StaEquation, Units: metLinear, impLinear,
elevationType documentation).
"""
from __future__ import annotations

import datetime as _dt
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from xml.sax.saxutils import quoteattr

import numpy as np

from trolley import units
from trolley.alignment import (Alignment, Arc, CantProfile, Clothoid, HorizontalAlignment, Line,
                               VerticalProfile)
from trolley.numbertext import parse_number
from trolley.stationing import StationEquation, StationNotFound, Stationing

__all__ = ["LandXmlError", "AlignmentChoiceError", "LandXmlDesign", "read_landxml", "parse_landxml",
           "alignment_names", "landxml_text", "JOIN_TOLERANCE_M", "DIRECTION_TOLERANCE_RAD",
           "GAP_REFUSE_M", "DIRECTION_REFUSE_RAD", "ZERO_LENGTH_M", "PROFILE_OVERLAP_TOLERANCE_M",
           "DEFAULT_RAIL_SPACING_M", "CoordinateSystemInfo", "coordinate_system"]

LANDXML_NS = "http://www.landxml.org/schema/LandXML-1.2"
#: A gap above this between where an element's geometry ends and the next element's Start (or
#: the last element's End in the file), or between an element's coordinates and its attributes,
#: is reported (joins) or refused (within one element).
JOIN_TOLERANCE_M = 1e-3
#: A direction break above this at a join is reported: 1e-4 rad is a 0.25 mm versine on a 10 m
#: chord across the join; real files carry up to 2e-5 rad from rounded coordinates.
DIRECTION_TOLERANCE_RAD = 1e-4
#: Joins farther apart than this, or breaking by more than DIRECTION_REFUSE_RAD, are not one
#: alignment: refused.
GAP_REFUSE_M = 0.1
DIRECTION_REFUSE_RAD = 1e-2
#: An alignment whose elements add up to a length this far (relative, and GAP_REFUSE_M) from its
#: own length attribute is refused: a stale or rounded total is noted, not a curve the wrong way
LENGTH_REFUSE_FRACTION = 0.01
#: Elements shorter than this are skipped with a note (the neighbours join across them).
ZERO_LENGTH_M = 1e-3
#: Vertical curves overlapping by less than this are accepted with a note.
PROFILE_OVERLAP_TOLERANCE_M = 1e-3
#: Distance within which a cant station counts as lying on an element join (station basis).
_BASIS_MATCH_M = 5e-3
#: Distance between rail centre lines used to turn appliedCant (a height) into an angle.
DEFAULT_RAIL_SPACING_M = 1.5

_LINEAR_CANT_TRANSITIONS = {"linear", "clothoid"}


class LandXmlError(ValueError):
    """A LandXML file that cannot be read as a design alignment (message names the element)."""


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _children(el: ET.Element, name: str) -> list[ET.Element]:
    return [c for c in el if _local(c.tag) == name]


def _describe(el: ET.Element, index: int | None = None) -> str:
    """``<Spiral> no. 2 (staStart="100.0", name="SP1")``: how errors name an element."""
    tag = _local(el.tag)
    text = f"<{tag}>"
    if index is not None:
        text += f" no. {index + 1}"
    attrs = [f'{k}="{el.get(k)}"' for k in ("staStart", "station", "name") if el.get(k) is not None]
    if attrs:
        text += " (" + ", ".join(attrs) + ")"
    return text


def _number(text: str | None, where: str, what: str) -> float:
    if text is None:
        raise LandXmlError(f"{where}: missing attribute {what!r}")
    try:
        value = parse_number(text.strip())
    except ValueError as exc:
        raise LandXmlError(f"{where}: {what}={exc}") from None
    if math.isnan(value):
        raise LandXmlError(f"{where}: {what}={text!r} is not a number")
    return value


def _finite(text: str | None, where: str, what: str) -> float:
    value = _number(text, where, what)
    if not math.isfinite(value):
        raise LandXmlError(f"{where}: {what}={text!r} must be finite")
    return value


def _radius_curvature(text: str | None, where: str, what: str) -> float:
    """1/R from a radius attribute; ``INF`` (straight) gives 0."""
    r = _number(text, where, what)
    if math.isinf(r):
        return 0.0
    if r == 0.0:
        raise LandXmlError(f"{where}: {what}={text!r}: a radius cannot be 0")
    return 1.0 / abs(r)


def _values(el: ET.Element, where: str, counts: tuple[int, ...], what: str) -> list[float]:
    text = (el.text or "").strip()
    if not text:
        if el.get("pntRef") is not None:
            raise LandXmlError(f"{where}: <{_local(el.tag)}> uses pntRef, which is not supported; "
                               f"write the coordinates in the element")
        raise LandXmlError(f"{where}: <{_local(el.tag)}> is empty, expected {what}")
    parts = text.split()
    if len(parts) not in counts:
        raise LandXmlError(f"{where}: <{_local(el.tag)}> holds {text!r}, expected {what}")
    out = []
    for p in parts:
        try:
            v = parse_number(p)
        except ValueError as exc:
            raise LandXmlError(f"{where}: <{_local(el.tag)}> value {exc}") from None
        if not math.isfinite(v):
            raise LandXmlError(f"{where}: <{_local(el.tag)}> value {p!r} must be finite")
        out.append(v)
    return out


def _point(parent: ET.Element, name: str, where: str, scale: float) -> complex:
    """Point child ``name`` as complex N + iE (metres); LandXML text is "N E [Z]"."""
    found = _children(parent, name)
    if not found:
        raise LandXmlError(f"{where}: missing <{name}>")
    n, e = _values(found[0], where, (2, 3), "'northing easting [elevation]'")[:2]
    return complex(n * scale, e * scale)


def _rot_sign(el: ET.Element, where: str) -> float:
    rot = el.get("rot")
    if rot is None:
        raise LandXmlError(f"{where}: missing attribute 'rot'")
    if rot not in ("cw", "ccw"):
        raise LandXmlError(f"{where}: rot={rot!r}, expected 'cw' or 'ccw'")
    return 1.0 if rot == "cw" else -1.0


def _bearing(d: complex) -> float:
    """Grid bearing (clockwise from north) of a complex N + iE direction."""
    return math.atan2(d.imag, d.real)


@dataclass
class _ParsedElement:
    element: object
    start: complex
    end: complex
    heading: float
    sta_start: float | None
    where: str
    label: str


def _zero_length_note(where: str, length_m: float, notes: list[str]) -> None:
    notes.append(f"{where}: skipped, zero length ({units.m_to_mm(length_m):.3f} mm)")


def _parse_line(el, where, scale, label, notes) -> _ParsedElement | None:
    start = _point(el, "Start", where, scale)
    end = _point(el, "End", where, scale)
    length = abs(end - start)
    if length < ZERO_LENGTH_M:
        _zero_length_note(where, length, notes)
        return None
    _check_attr_length(el, where, scale, length, notes)
    return _ParsedElement(Line(length), start, end, _bearing(end - start), _sta(el, where, scale),
                          where, label)


def _parse_curve(el, where, scale, label, notes) -> _ParsedElement | None:
    sign = _rot_sign(el, where)
    if el.get("crvType") not in (None, "arc", "chord"):
        raise LandXmlError(f"{where}: crvType={el.get('crvType')!r} is not supported")
    start = _point(el, "Start", where, scale)
    end = _point(el, "End", where, scale)
    attr_length = (None if el.get("length") is None
                   else _finite(el.get("length"), where, "length") * scale)
    if abs(end - start) < ZERO_LENGTH_M and (attr_length is None or attr_length < ZERO_LENGTH_M):
        _zero_length_note(where, abs(end - start) if attr_length is None else attr_length, notes)
        return None
    centre = _point(el, "Center", where, scale)
    radius = abs(start - centre)
    if radius <= 0.0:
        raise LandXmlError(f"{where}: Center coincides with Start")
    off = abs(end - centre) - radius
    _tolerate(f"{where}: End is {abs(end - centre):.4f} m from Center but Start is {radius:.4f} m "
              f"({units.m_to_mm(off):+.2f} mm)", abs(off), 0.0, notes,
              used="the arc of radius |Start - Center| is used", refused="not a circular arc")
    if el.get("radius") is not None:
        r_attr = abs(_finite(el.get("radius"), where, "radius")) * scale
        _tolerate(f"{where}: radius={el.get('radius')} disagrees with the coordinates "
                  f"(|Start - Center| = {radius:.4f} m, {units.m_to_mm(r_attr - radius):+.2f} mm)",
                  abs(r_attr - radius), 0.0, notes, used="the coordinates are used",
                  refused="not one element")
    # multiplying N + iE by exp(i a) turns clockwise: the swept angle in the rot direction
    ratio = (end - centre) / (start - centre)
    swept = (sign * math.atan2(ratio.imag, ratio.real)) % (2.0 * math.pi)
    length = radius * swept
    _check_attr_length(el, where, scale, length, notes)
    # the centre lies to the right of the direction of travel for cw, to the left for ccw
    tangent = (centre - start) / (1j * sign * radius)
    return _ParsedElement(Arc(length, sign / radius), start, end, _bearing(tangent),
                          _sta(el, where, scale), where, label)


def _parse_spiral(el, where, scale, label, notes) -> _ParsedElement | None:
    spi = el.get("spiType")
    if spi is None:
        raise LandXmlError(f"{where}: missing attribute 'spiType'")
    if spi != "clothoid":
        raise LandXmlError(f"{where}: spiType={spi!r} is not supported (only 'clothoid')")
    sign = _rot_sign(el, where)
    length = _finite(el.get("length"), where, "length") * scale
    if length < 0.0:
        raise LandXmlError(f"{where}: length={el.get('length')!r} must be >= 0")
    if length < ZERO_LENGTH_M:
        _zero_length_note(where, length, notes)
        return None
    k0 = _radius_curvature(el.get("radiusStart"), where, "radiusStart") / scale
    k1 = _radius_curvature(el.get("radiusEnd"), where, "radiusEnd") / scale
    if k0 == k1:
        raise LandXmlError(f"{where}: radiusStart equals radiusEnd: not a transition")
    start = _point(el, "Start", where, scale)
    pi = _point(el, "PI", where, scale)
    end = _point(el, "End", where, scale)
    if abs(pi - start) <= 0.0:
        raise LandXmlError(f"{where}: PI coincides with Start")
    return _ParsedElement(Clothoid(length, sign * k0, sign * k1), start, end, _bearing(pi - start),
                          _sta(el, where, scale), where, label)


def _sta(el, where, scale) -> float | None:
    text = el.get("staStart")
    return None if text is None else _finite(text, where, "staStart") * scale


def _check_attr_length(el, where, scale, length, notes) -> None:
    if el.get("length") is not None:
        l_attr = _finite(el.get("length"), where, "length") * scale
        _tolerate(f"{where}: length={el.get('length')} disagrees with the coordinates by "
                  f"{units.m_to_mm(l_attr - length):+.2f} mm", abs(l_attr - length), 0.0, notes,
                  used="the coordinates are used", refused="not one element")


_PARSERS = {"Line": _parse_line, "Curve": _parse_curve, "Spiral": _parse_spiral}


def _namespace(tag: str) -> str:
    return tag[1:].split("}", 1)[0] if isinstance(tag, str) and tag.startswith("{") else ""


def _skippable(el: ET.Element, parent: ET.Element) -> bool:
    """``<Feature>`` (user data) and elements of another namespace (vendor extensions)."""
    return _local(el.tag) == "Feature" or _namespace(el.tag) != _namespace(parent.tag)


def _tolerate(text: str, miss_m: float, turn_rad: float, notes: list[str], *, used: str,
              refused: str) -> None:
    """Refuse a disagreement above GAP_REFUSE_M or DIRECTION_REFUSE_RAD; note one above
    JOIN_TOLERANCE_M or DIRECTION_TOLERANCE_RAD. ``text`` says where and how much."""
    if miss_m > GAP_REFUSE_M or abs(turn_rad) > DIRECTION_REFUSE_RAD:
        raise LandXmlError(f"{text}: {refused} (refused above {units.m_to_mm(GAP_REFUSE_M):.0f} mm "
                           f"or {DIRECTION_REFUSE_RAD} rad)")
    if miss_m > JOIN_TOLERANCE_M or abs(turn_rad) > DIRECTION_TOLERANCE_RAD:
        notes.append(f"{text} ({used})")


def _join_check(text: str, gap_m: float, turn_rad: float, notes: list[str]) -> None:
    _tolerate(text, gap_m, turn_rad, notes, used="each element is used from its own Start and direction",
              refused="the elements do not join")


def _horizontal(al: ET.Element, aname: str, scale: float, sta_start: float,
                notes: list[str]) -> tuple[HorizontalAlignment, list[_ParsedElement]]:
    geoms = _children(al, "CoordGeom")
    if not geoms:
        raise LandXmlError(f"{aname}: no <CoordGeom>")
    if len(geoms) > 1:
        notes.append(f"{aname}: {len(geoms)} <CoordGeom>; the first one is used")
    parsed: list[_ParsedElement] = []
    for i, el in enumerate(geoms[0]):
        tag = _local(el.tag)
        if not tag or _skippable(el, geoms[0]):  # comments; Feature and extensions (noted later)
            continue
        where = f"{aname}, CoordGeom {_describe(el, i)}"
        if tag not in _PARSERS:
            raise LandXmlError(f"{where}: element type <{tag}> is not supported "
                               f"(Line, Curve, Spiral)")
        p = _PARSERS[tag](el, where, scale, _describe(el, i), notes)
        if p is not None:
            parsed.append(p)
    if not parsed:
        raise LandXmlError(f"{aname}: <CoordGeom> holds no Line, Curve or Spiral")
    try:
        hz = HorizontalAlignment.from_anchored_elements(
            [p.start.imag for p in parsed], [p.start.real for p in parsed],
            [p.heading for p in parsed], [p.element for p in parsed], sta_start)
    except ValueError as exc:
        raise LandXmlError(f"{aname}: {exc}") from None
    for i in range(len(parsed) - 1):
        gap, turn = float(hz.join_gap_m[i]), float(hz.join_turn_rad[i])
        _join_check(f"{parsed[i + 1].where}: its Start is {units.m_to_mm(gap):.2f} mm from where "
                    f"{parsed[i].label} ends and its direction breaks by {turn:.2e} rad there",
                    gap, turn, notes)
    last = parsed[-1]
    miss = abs(complex(hz.element_end_N_m[-1], hz.element_end_E_m[-1]) - last.end)
    _join_check(f"{last.where}: its geometry ends {units.m_to_mm(miss):.2f} mm from its End in the "
                f"file", miss, 0.0, notes)
    return hz, parsed


def _check_sta_starts(parsed: list[_ParsedElement], hz: HorizontalAlignment,
                      stationing: Stationing | None, notes: list[str]) -> None:
    """``staStart`` of each element against the lengths before it (internal or drawing station)."""
    internal = hz.element_chainage_m[:-1]
    drawing = internal if stationing is None else stationing.station(internal)
    before = 0.0  # a disagreement is reported where it begins, not at every later element
    for p, s_int, s_dr in zip(parsed, internal, drawing):
        if p.sta_start is None:
            continue
        miss = p.sta_start - (s_dr if abs(p.sta_start - s_dr) < abs(p.sta_start - s_int) else s_int)
        # (an element that agrees again after one that did not is not a disagreement)
        if abs(miss) > JOIN_TOLERANCE_M and abs(miss - before) > JOIN_TOLERANCE_M:
            notes.append(f"{p.where}: staStart is {units.m_to_mm(miss):+.1f} mm from the lengths of "
                         f"the elements before it ({s_int:.4f}); the lengths are used")
        before = miss


def _station_equations(al: ET.Element, aname: str, scale: float, hz: HorizontalAlignment,
                       notes: list[str]) -> Stationing | None:
    els = _children(al, "StaEquation")
    if not els:
        return None
    eqs = []
    for i, el in enumerate(els):
        where = f"{aname}, <StaEquation> no. {i + 1} (staInternal=\"{el.get('staInternal')}\")"
        internal = _finite(el.get("staInternal"), where, "staInternal") * scale
        ahead = _finite(el.get("staAhead"), where, "staAhead") * scale
        back = None if el.get("staBack") is None else _finite(el.get("staBack"), where, "staBack") * scale
        inc = el.get("staIncrement", "increasing")
        if inc not in ("increasing", "decreasing"):
            raise LandXmlError(f"{where}: staIncrement={inc!r}, expected 'increasing' or 'decreasing'")
        eqs.append((internal, StationEquation(internal, ahead, back, inc == "increasing"), where))
    eqs.sort(key=lambda e: e[0])
    try:
        st = Stationing(hz.start_chainage_m, hz.end_chainage_m, [e[1] for e in eqs])
    except ValueError as exc:
        raise LandXmlError(f"{aname}: {exc}") from None
    for k, (_, eq, where) in enumerate(eqs):
        if eq.back_m is not None and k + 1 < len(st.region_start_m) and \
                st.region_start_m[k + 1] > st.region_start_m[k]:
            reached = st.back_station(k)
            if abs(reached - eq.back_m) > JOIN_TOLERANCE_M:
                notes.append(f"{where}: staBack is {eq.back_m:.4f} but the stationing behind it "
                             f"reaches {reached:.4f} ({units.m_to_mm(eq.back_m - reached):.1f} mm); "
                             f"staAhead is used")
    return st


def _near_joins(s: np.ndarray, hz: HorizontalAlignment) -> int:
    """How many of the internal stations ``s`` fall on element joins (cant ramps start and end there)."""
    d = np.abs(np.asarray(s, dtype=float)[:, None] - hz.element_chainage_m[None, :])
    return int(np.sum(np.min(d, axis=1) <= _BASIS_MATCH_M)) if d.size else 0


def _station_basis(aname: str, hz: HorizontalAlignment, stationing: Stationing | None,
                   cant_raw: list[float], pvi_raw: list[float], notes: list[str]) -> bool:
    """True when the cant and PVI stations of the file are drawing stations (after the station
    equations) rather than internal ones (the schema's ``station`` type).

    Only a file with station equations can differ. A reading that puts a cant station off the
    alignment loses; then the one whose PVIs reach less far beyond the alignment's ends (whole
    metres: a profile may run on a little); then the one in which more cant stations fall on
    element joins (cant ramps run along the transitions), and the last PVI on the alignment end;
    a tie is internal.
    """
    if stationing is None or not stationing.equations or not (cant_raw or pvi_raw):
        return False
    lo, hi = hz.start_chainage_m - JOIN_TOLERANCE_M, hz.end_chainage_m + JOIN_TOLERANCE_M

    def score(cant_internal, pvi_internal) -> tuple[int, int, int]:
        """(- cant stations off the alignment, - metres of PVIs beyond its ends, stations on joins
        or the end)."""
        c = np.asarray(cant_internal, dtype=float)
        v = np.asarray(pvi_internal, dtype=float)
        off = int(np.sum((c < lo) | (c > hi)))
        beyond = int(round(float(np.sum(np.maximum(0.0, np.maximum(lo - v, v - hi)))))) if v.size else 0
        hit = _near_joins(c, hz)
        if v.size and abs(v[-1] - hz.end_chainage_m) <= _BASIS_MATCH_M:
            hit += 1
        return -off, -beyond, hit

    s_int = score(cant_raw, pvi_raw)
    try:
        cant_dr = stationing.internal_of(cant_raw) if cant_raw else np.empty(0)
        pvi_dr = stationing.internal_of(pvi_raw) if pvi_raw else np.empty(0)
        s_dr = score(cant_dr, pvi_dr)
    except StationNotFound:
        s_dr = (-len(cant_raw) - 1, 0, 0)
    drawing = s_dr > s_int
    kind = ("drawing stations (after the station equations)" if drawing
            else "internal stations (the schema's 'station' type)")
    notes.append(f"{aname}: the alignment has {len(stationing.equations)} station equation(s); cant "
                 f"and PVI stations read as {kind}: as drawing stations {s_dr[2]} fall on element "
                 f"joins or the end, {-s_dr[0]} cant stations off the alignment and the PVIs reach "
                 f"{-s_dr[1]} m beyond its ends, as internal stations {s_int[2]}, {-s_int[0]} and "
                 f"{-s_int[1]} m")
    return drawing


def _to_internal(values: list[float], wheres: list[str], drawing: bool,
                 stationing: Stationing | None) -> np.ndarray:
    if not drawing:
        return np.asarray(values, dtype=float)
    try:
        return stationing.internal_of(values)
    except StationNotFound as exc:
        raise LandXmlError(f"{wheres[exc.index]}: station {values[exc.index]!r} is in no part of the "
                           f"drawing stationing (a gap left by a station equation)") from None


def _prof_align(al: ET.Element, aname: str, notes: list[str]) -> tuple[ET.Element, str] | None:
    found = [(prof, pa) for prof in _children(al, "Profile") for pa in _children(prof, "ProfAlign")]
    if not found:
        return None
    prof, pa = found[0]
    if len(found) > 1:
        others = ", ".join(repr(p.get("name")) for _, p in found[1:])
        notes.append(f"{aname}: {len(found)} <ProfAlign>; {pa.get('name')!r} is used, not {others}")
    return pa, f"{aname}, {_describe(prof)} {_describe(pa)}"


def _pvis(pa: ET.Element, pwhere: str, scale: float, elev_scale: float):
    sta, elev, length, radius, wheres = [], [], [], [], []
    for i, el in enumerate(pa):
        tag = _local(el.tag)
        if not tag or _skippable(el, pa):
            continue
        where = f"{pwhere} {_describe(el, i)}"
        curve, r = 0.0, 0.0
        if tag in ("ParaCurve", "CircCurve"):
            curve = _finite(el.get("length"), where, "length") * scale
            if curve < 0.0:
                raise LandXmlError(f"{where}: length={el.get('length')!r} must be >= 0")
            if tag == "CircCurve":
                # the sign convention of the radius varies: crest/sag come from the grades
                r = abs(_finite(el.get("radius"), where, "radius")) * scale
                if r == 0.0:
                    raise LandXmlError(f"{where}: radius must not be 0")
        elif tag != "PVI":
            raise LandXmlError(f"{where}: <{tag}> is not supported (PVI, ParaCurve, CircCurve)")
        s, h = _values(el, where, (2,), "'station elevation'")
        sta.append(s * scale)
        elev.append(h * elev_scale)
        length.append(curve)
        radius.append(r)
        wheres.append(where)
    return sta, elev, length, radius, wheres


def _in_order(sta_internal, raw_m, wheres: list[str]) -> None:
    """Refuse a station that does not come after the one before it, naming the element and the
    stations as the file gives them (in metres; drawing stations where the file has them)."""
    s = np.asarray(sta_internal, dtype=float)
    bad = np.flatnonzero(np.diff(s) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise LandXmlError(f"{wheres[i]}: station {raw_m[i]:.4f} m does not come after the one before it "
                           f"({raw_m[i - 1]:.4f} m)")


def _profile(pa: ET.Element, pwhere: str, pvis, sta_internal: np.ndarray,
             notes: list[str]) -> VerticalProfile:
    raw, elev, length, radius, wheres = pvis
    sta = sta_internal
    if len(sta) < 2:
        raise LandXmlError(f"{pwhere}: needs at least two PVIs")
    _in_order(sta, raw, wheres)
    for k in (0, len(sta) - 1):
        if length[k] != 0.0 or radius[k] != 0.0:
            raise LandXmlError(f"{wheres[k]}: the first and last PVI cannot carry a curve")
    try:
        # overlaps are checked below, where the elements can be named
        profile = VerticalProfile.from_pvis(sta, elev, length, radius, overlap_tolerance_m=math.inf)
    except ValueError as exc:
        raise LandXmlError(f"{pwhere}: {exc}") from None
    for k in np.flatnonzero(np.asarray(radius) > 0):
        # the circle is fixed by the radius and the grades; its length is only a check
        # (PVI heights rounded to the mm move it by centimetres on long curves)
        if abs(profile.curve_length_m[k] - length[k]) > max(0.1, 0.01 * length[k]):
            raise LandXmlError(f"{wheres[k]}: length={length[k]!r} but a circle of radius "
                               f"{radius[k]!r} between the adjacent grades is "
                               f"{profile.curve_length_m[k]:.3f} m long")
    overlap = profile.curve_end_m[:-1] - profile.curve_start_m[1:]
    for k in np.flatnonzero(overlap > 1e-9 * max(1.0, float(np.max(np.abs(sta))))):
        text = (f"{wheres[k]}: its vertical curve (ends at {profile.curve_end_m[k]:.4f}) and the next "
                f"one (begins at {profile.curve_start_m[k + 1]:.4f}) overlap by "
                f"{units.m_to_mm(overlap[k]):.3f} mm")
        if overlap[k] > PROFILE_OVERLAP_TOLERANCE_M:
            raise LandXmlError(f"{text} (refused above {units.m_to_mm(PROFILE_OVERLAP_TOLERANCE_M):.0f} mm)")
        notes.append(f"{text} (accepted below {units.m_to_mm(PROFILE_OVERLAP_TOLERANCE_M):.0f} mm)")
    return profile


def _cant(al: ET.Element, aname: str, hz: HorizontalAlignment, u: "_Units",
          rail_spacing_m: float | None, stationing: Stationing | None, drawing: bool,
          notes: list[str]) -> CantProfile | None:
    cants = _children(al, "Cant")
    if not cants:
        return None
    cant_el = cants[0]
    cwhere = f"{aname}, {_describe(cant_el)}"
    if len(cants) > 1:
        notes.append(f"{aname}: {len(cants)} <Cant> elements; the first ({_describe(cant_el)}) is used")
    if rail_spacing_m is None:
        # the schema gives gauge in metres (feet in an imperial file)
        rail_spacing_m = _finite(cant_el.get("gauge"), cwhere, "gauge") * u.gauge
    if not rail_spacing_m > 0:
        raise LandXmlError(f"{cwhere}: rail spacing {rail_spacing_m!r} must be > 0")
    raw, heights, curvs, flips, wheres = _cant_stations(cant_el, cwhere, u)
    if not raw:
        raise LandXmlError(f"{cwhere}: no <CantStation>")
    sta = _to_internal(raw, wheres, drawing, stationing)
    _in_order(sta, raw, wheres)
    lo, hi = hz.start_chainage_m, hz.end_chainage_m
    for s, r, where in zip(sta, raw, wheres):
        if s > hi + JOIN_TOLERANCE_M or s < lo - JOIN_TOLERANCE_M:
            side = "beyond the alignment end" if s > hi else "before the alignment start"
            ends = (f"{lo:.4f} .. {hi:.4f}" if stationing is None else
                    f"{lo:.4f} .. {hi:.4f} internal, {stationing.station(lo):.4f} .. "
                    f"{stationing.station(hi):.4f} drawing")
            raise LandXmlError(f"{where}: station {r / u.linear:.4f} lies {side} by "
                               f"{(s - hi if s > hi else lo - s):.4f} m (the alignment runs {ends})")
    ang = []
    for s, height_m, curv, flip, where in zip(sta, heights, curvs, flips, wheres):
        sign = curv
        if curv is None:
            sign = _side_of_curve(hz, s)
            if sign == 0.0 and height_m != 0.0:
                raise LandXmlError(f"{where}: missing attribute 'curvature' and no horizontal curve "
                                   f"at this station to take the side from")
        elif height_m != 0.0 and _side_of_curve(hz, s) == -curv:
            # the stated side contradicts the geometry: used as written, but said (a mixed-up
            # attribute makes the cant change sides inside a curve)
            turns = "clockwise (cw)" if curv < 0 else "counter-clockwise (ccw)"
            rail = "outer" if flip < 0 else "inner"
            notes.append(f"{where}: curvature=\"{'cw' if curv > 0 else 'ccw'}\" but the alignment turns {turns} "
                         f"here: used as written, this cant raises the {rail} rail (a cant on the inner rail is "
                         "written with the curve's side and adverse=\"true\")")
        sign *= flip
        if abs(height_m) >= rail_spacing_m:
            raise LandXmlError(f"{where}: appliedCant {units.m_to_mm(height_m):.1f} mm exceeds the "
                               f"rail spacing {rail_spacing_m} m")
        ang.append(sign * math.asin(height_m / rail_spacing_m))
    try:
        return CantProfile.from_stations(sta, ang)
    except ValueError as exc:
        raise LandXmlError(f"{cwhere}: {exc}") from None


def _cant_stations(cant_el: ET.Element, cwhere: str, u: "_Units"):
    """Raw stations (m, as in the file), rail height differences (m), sides (``cw`` +1, ``ccw``
    -1, None: from the curve), ``adverse`` flips (-1) and element names."""
    raw, heights, curvs, flips, wheres = [], [], [], [], []
    for i, el in enumerate(_children(cant_el, "CantStation")):
        where = f"{cwhere} {_describe(el, i)}"
        raw.append(_finite(el.get("station"), where, "station") * u.linear)
        heights.append(_finite(el.get("appliedCant"), where, "appliedCant") * u.cant)
        trans = el.get("transitionType")
        if trans is not None and trans not in _LINEAR_CANT_TRANSITIONS:
            raise LandXmlError(f"{where}: transitionType={trans!r} is not supported (linear ramps)")
        curv = el.get("curvature")
        if curv is None:
            sign = None
        elif curv in ("cw", "ccw"):
            sign = 1.0 if curv == "cw" else -1.0
        else:
            raise LandXmlError(f"{where}: curvature={curv!r}, expected 'cw' or 'ccw'")
        adverse = el.get("adverse")
        if adverse is not None and adverse not in ("true", "false", "1", "0"):
            raise LandXmlError(f"{where}: adverse={adverse!r} is not a boolean")
        curvs.append(sign)
        flips.append(-1.0 if adverse in ("true", "1") else 1.0)
        wheres.append(where)
    return raw, heights, curvs, flips, wheres


def _side_of_curve(hz: HorizontalAlignment, s: float) -> float:
    """Sign of the horizontal curvature at (or just either side of) chainage ``s``."""
    k = hz.evaluate(np.array([s, s + 1e-3, s - 1e-3])).rho_h_1_m
    nz = k[k != 0.0]
    return float(np.sign(nz[0])) if nz.size else 0.0


#: Children each element uses; anything else in it is skipped with a note.
_USED_CHILDREN = {"Alignment": {"CoordGeom", "Profile", "Cant", "StaEquation", "Start"},
                  "Profile": {"ProfAlign"}, "Cant": {"CantStation"}}


def _skipped_notes(al: ET.Element, aname: str, notes: list[str]) -> None:
    """One note per kind of element the import does not use (Feature, vendor extensions, ...)."""
    counts: dict[tuple[str, str], int] = {}

    def walk(el: ET.Element, path: str) -> None:
        used = _USED_CHILDREN.get(_local(el.tag))
        for c in el:
            tag = _local(c.tag)
            if not tag:
                continue
            if _skippable(c, el) or (used is not None and tag not in used):
                ns = _namespace(c.tag)
                what = f"<{tag}>" + (f" ({ns} extension)" if ns != _namespace(el.tag) else "")
                counts[(path, what)] = counts.get((path, what), 0) + 1
                continue
            walk(c, f"{path}/{tag}")

    walk(al, "")
    for (path, what), n in counts.items():
        place = f"in {path.lstrip('/')}" if path else "in the alignment"
        notes.append(f"{aname}: skipped {n} {what} {place} (not used by the import)")


@dataclass(frozen=True)
class CoordinateSystemInfo:
    """The ``<CoordinateSystem>`` element of a LandXML 1.2 file (all attributes optional).

    Attributes
    ----------
    name : ``name`` (e.g. "ETRS89 / UTM zone 32N").
    epsg_code : ``epsgCode`` as an integer ("25832", "EPSG:25832" and "urn:ogc:def:crs:EPSG::25832"
        all give 25832).
    ogc_wkt : ``ogcWktCode`` when it holds WKT.
    proj4 : a PROJ string (``+proj=...``) when ``ogcWktCode`` holds one instead of WKT (some
        exporters write it there; the schema has no attribute of its own for it).
    horizontal_datum, vertical_datum : ``horizontalDatum``, ``verticalDatum`` (e.g. "DHHN2016").
    horizontal_crs_name, vertical_crs_name : ``horizontalCoordinateSystemName``,
        ``verticalCoordinateSystemName``.
    """

    name: str | None = None
    epsg_code: int | None = None
    ogc_wkt: str | None = None
    proj4: str | None = None
    horizontal_datum: str | None = None
    vertical_datum: str | None = None
    horizontal_crs_name: str | None = None
    vertical_crs_name: str | None = None

    @property
    def crs_text(self) -> str | None:
        """What ``pyproj.CRS.from_user_input`` takes: "EPSG:n", else the WKT, else the PROJ string."""
        if self.epsg_code is not None:
            return f"EPSG:{self.epsg_code}"
        return self.ogc_wkt or self.proj4


def _parse_root(text: str) -> ET.Element:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise LandXmlError(f"not well-formed XML: {exc}") from None
    if _local(root.tag) != "LandXML":
        raise LandXmlError(f"root element is <{_local(root.tag)}>, expected <LandXML>")
    return root


def coordinate_system(text: str) -> CoordinateSystemInfo | None:
    """The ``<CoordinateSystem>`` of a LandXML document, or None when it has none.

    Parameters
    ----------
    text : the XML document.

    Returns
    -------
    CoordinateSystemInfo or None

    Raises
    ------
    LandXmlError
        Malformed XML, or an ``epsgCode`` that is not a number.
    """
    return _coordinate_system(_parse_root(text))


def _coordinate_system(root: ET.Element) -> CoordinateSystemInfo | None:
    found = _children(root, "CoordinateSystem")
    if not found:
        return None
    cs = found[0]

    def attr(name: str) -> str | None:
        value = cs.get(name)
        return value.strip() if value is not None and value.strip() else None

    epsg = attr("epsgCode")
    code = None
    if epsg is not None:
        digits = epsg.rsplit(":", 1)[-1].strip()
        if not digits.isdigit():
            raise LandXmlError(f"<CoordinateSystem>: epsgCode={epsg!r} is not an EPSG number")
        code = int(digits)
    wkt = attr("ogcWktCode")
    proj4 = None
    if wkt is not None and wkt.startswith("+"):
        wkt, proj4 = None, wkt
    return CoordinateSystemInfo(name=attr("name"), epsg_code=code, ogc_wkt=wkt, proj4=proj4,
                                horizontal_datum=attr("horizontalDatum"),
                                vertical_datum=attr("verticalDatum"),
                                horizontal_crs_name=attr("horizontalCoordinateSystemName"),
                                vertical_crs_name=attr("verticalCoordinateSystemName"))


_XML_DECLARATION = re.compile(rb"""^<\?xml[^>]*?encoding\s*=\s*["']([A-Za-z0-9._:-]+)["']""")


def decoded_landxml(data: bytes) -> str:
    """The text of a LandXML file's bytes, in the encoding the file declares (XML 1.0, 4.3.3).

    A byte-order mark (UTF-8, UTF-16, UTF-32) decides first, then the XML declaration's
    ``encoding``; without either the text is UTF-8. The declaration of the returned text says
    UTF-8, so that writing it out as UTF-8 keeps it true.

    Raises
    ------
    LandXmlError : an unknown encoding, or bytes that are not valid in the declared one (naming
        the byte).
    """
    import codecs

    boms = ((codecs.BOM_UTF32_LE, "utf-32"), (codecs.BOM_UTF32_BE, "utf-32"), (codecs.BOM_UTF8, "utf-8-sig"),
            (codecs.BOM_UTF16_LE, "utf-16"), (codecs.BOM_UTF16_BE, "utf-16"))
    encoding = next((enc for bom, enc in boms if data.startswith(bom)), None)
    declared = _XML_DECLARATION.match(data.lstrip()[:200]) if encoding is None else None
    if encoding is None:
        encoding = declared.group(1).decode("ascii") if declared else "utf-8"
    try:
        codecs.lookup(encoding)
    except LookupError:
        raise LandXmlError(f"the XML declaration names an unknown encoding {encoding!r}") from None
    try:
        text = data.decode(encoding)
    except UnicodeDecodeError as e:
        raise LandXmlError(f"not valid {encoding} text ({e.reason} at byte {e.start})") from None
    return re.sub(r"""^(\s*<\?xml[^>]*?encoding\s*=\s*)["'][^"']*["']""", r'\1"UTF-8"', text, count=1)


class AlignmentChoiceError(LandXmlError):
    """The file holds several alignments and none (or an unknown one) was named.

    Attributes
    ----------
    names : the ``Alignment/@name`` values in the file, in file order.
    """

    def __init__(self, message: str, names: list[str]) -> None:
        super().__init__(message)
        self.names = names


@dataclass(frozen=True)
class LandXmlDesign:
    """One alignment read from a LandXML file, with what the reader has to tell about it.

    Attributes
    ----------
    alignment : the design geometry (SI; chainage = internal station).
    notes : what was skipped, tolerated or reported (element named in each), in file order.
    names : every ``Alignment/@name`` in the file.
    coordinate_system : the file's ``<CoordinateSystem>``, if any.
    """

    alignment: Alignment
    notes: tuple[str, ...]
    names: tuple[str, ...]
    coordinate_system: CoordinateSystemInfo | None


def _alignments(root: ET.Element) -> list[ET.Element]:
    return [el for el in root.iter() if _local(el.tag) == "Alignment"]


def alignment_names(text: str) -> list[str]:
    """``Alignment/@name`` of every alignment in a LandXML document, in file order.

    Raises
    ------
    LandXmlError
        Malformed XML or not a LandXML document.
    """
    return [a.get("name") or "" for a in _alignments(_parse_root(text))]


def read_landxml(text: str, alignment_name: str | None = None, *,
                 rail_spacing_m: float | None = DEFAULT_RAIL_SPACING_M) -> LandXmlDesign:
    """Read one ``<Alignment>`` of a LandXML 1.2 document, with notes on what was tolerated.

    Parameters
    ----------
    text : the XML document.
    alignment_name : ``Alignment/@name`` to read; may be omitted when the file holds one.
    rail_spacing_m : distance between the rail centre lines that turns ``appliedCant`` into the
        cant angle asin(appliedCant / rail_spacing); ``None`` uses the ``gauge`` attribute of
        ``<Cant>``.

    Returns
    -------
    LandXmlDesign
        The alignment (horizontal, first ``<ProfAlign>``, ``<Cant>``, station equations) and
        the notes: skipped elements (``Feature``, extensions, zero-length elements), joins with a
        gap above :data:`JOIN_TOLERANCE_M` or a direction break above
        :data:`DIRECTION_TOLERANCE_RAD`, vertical curves overlapping by less than
        :data:`PROFILE_OVERLAP_TOLERANCE_M`, a declared length that disagrees with the elements,
        how cant stations were read against station equations.

    Raises
    ------
    AlignmentChoiceError
        Several alignments and no ``alignment_name``, no alignment of that name, or several.
    LandXmlError
        Malformed XML, missing or malformed attributes, unsupported element types, elements
        that do not join (gap above :data:`GAP_REFUSE_M` or a break above
        :data:`DIRECTION_REFUSE_RAD`), a cant station off the alignment. The message names the
        element.
    """
    root = _parse_root(text)
    u = _units(root)
    found = _alignments(root)
    if not found:
        raise LandXmlError("no <Alignment> in the file")
    names = [a.get("name") or "" for a in found]
    listing = ", ".join(repr(n) for n in names)
    if alignment_name is None:
        if len(found) > 1:
            raise AlignmentChoiceError(f"the file holds {len(found)} alignments ({listing}); choose "
                                       f"one by name", names)
        al = found[0]
    else:
        chosen = [a for a in found if a.get("name") == alignment_name]
        if not chosen:
            raise AlignmentChoiceError(f"no <Alignment name={alignment_name!r}> (found {listing})",
                                       names)
        if len(chosen) > 1:
            # the first one would be taken without a word, and the others never
            raise AlignmentChoiceError(f"{len(chosen)} alignments are named {alignment_name!r} (found {listing}): "
                                       "a name must pick one; rename them in the design tool", names)
        al = chosen[0]
    aname = f"<Alignment name={al.get('name')!r}>"
    for attr in ("name", "staStart", "length"):
        if al.get(attr) is None:
            raise LandXmlError(f"{aname}: missing attribute {attr!r}")
    notes: list[str] = []
    if u.note:
        notes.append(u.note)
    sta_start = _finite(al.get("staStart"), aname, "staStart") * u.linear
    length = _finite(al.get("length"), aname, "length") * u.linear
    hz, parsed = _horizontal(al, aname, u.linear, sta_start, notes)
    if abs(hz.length_m - length) > max(GAP_REFUSE_M, LENGTH_REFUSE_FRACTION * length):
        # an element the wrong way round (rot) or of another length: the file's own total says so
        raise LandXmlError(f"{aname}: length={al.get('length')} but its elements add up to "
                           f"{hz.length_m / u.linear:.4f}: an element's rot, length or coordinates are wrong "
                           f"(refused above {100 * LENGTH_REFUSE_FRACTION:g} % and "
                           f"{units.m_to_mm(GAP_REFUSE_M):.0f} mm)")
    if abs(hz.length_m - length) > JOIN_TOLERANCE_M:
        notes.append(f"{aname}: length={al.get('length')} but its elements add up to "
                     f"{hz.length_m / u.linear:.4f} ({units.m_to_mm(length - hz.length_m):+.1f} mm); "
                     f"the elements are used")
    stationing = _station_equations(al, aname, u.linear, hz, notes)
    _check_sta_starts(parsed, hz, stationing, notes)
    prof = _prof_align(al, aname, notes)
    pvis = None if prof is None else _pvis(prof[0], prof[1], u.linear, u.elevation)
    cant_raw: list[float] = []
    if _children(al, "Cant"):
        cant_raw = _cant_stations(_children(al, "Cant")[0], aname, u)[0]
    drawing = _station_basis(aname, hz, stationing, cant_raw, [] if pvis is None else pvis[0], notes)
    profile = None
    if prof is not None:
        profile = _profile(prof[0], prof[1], pvis, _to_internal(pvis[0], pvis[4], drawing, stationing),
                           notes)
        p0, p1 = float(profile.chainage_m[0]), float(profile.chainage_m[-1])
        if p0 > hz.start_chainage_m + JOIN_TOLERANCE_M or p1 < hz.end_chainage_m - JOIN_TOLERANCE_M:
            notes.append(f"{prof[1]}: the profile covers {p0:.4f} .. {p1:.4f}, the alignment "
                         f"{hz.start_chainage_m:.4f} .. {hz.end_chainage_m:.4f} (internal stations): the heights "
                         "beyond the profile are extended along its end grades")
    cant = _cant(al, aname, hz, u, rail_spacing_m, stationing, drawing, notes)
    _skipped_notes(al, aname, notes)
    alignment = Alignment(hz, profile, cant, name=al.get("name") or "", stationing=stationing)
    return LandXmlDesign(alignment, tuple(notes), tuple(names), _coordinate_system(root))


def parse_landxml(text: str, alignment_name: str | None = None, *,
                  rail_spacing_m: float | None = DEFAULT_RAIL_SPACING_M) -> Alignment:
    """The alignment of :func:`read_landxml` (its notes dropped: for files imported before).

    Parameters and exceptions as :func:`read_landxml`.

    Returns
    -------
    Alignment
    """
    return read_landxml(text, alignment_name, rail_spacing_m=rail_spacing_m).alignment


@dataclass(frozen=True)
class _Units:
    """Metres per file unit: lengths/coordinates/stations, elevations, cant values, gauge."""

    linear: float
    elevation: float
    cant: float
    gauge: float
    note: str | None = None


_METRIC_M = {"meter": 1.0, "millimeter": 1e-3, "centimeter": 1e-2, "kilometer": 1e3}
_IMPERIAL_M = {"foot": units.INTERNATIONAL_FOOT_M, "USSurveyFoot": units.US_SURVEY_FOOT_M,
               "inch": units.INCH_M, "mile": units.INTERNATIONAL_MILE_M}


def _units(root: ET.Element) -> _Units:
    """``<Units>``: ``<Metric>`` or ``<Imperial>`` (schema types metLinear, impLinear and
    elevationType; cant values are mm, or inches in an imperial file).

    The schema allows one of them (``xs:choice``). A file holding several is read only when they
    all give the same conversions (a tool that repeats its ``<Metric>``), with a note; when they
    disagree it is refused: the numbers are in one of the units and nothing in the file says
    which, and the wrong one scales every coordinate, station and height (a metre read as a foot:
    3.28 times; a cant inch read as a millimetre: 25.4 times). A ``<Metric>`` beside an
    ``<Imperial>`` always disagrees (no metric length unit is an imperial one, and cant values are
    mm in the one and inches in the other), so such a file is always refused.
    """
    units_el = [el for el in root if _local(el.tag) == "Units"]
    if not units_el:
        raise LandXmlError("missing <Units>")
    kinds = [c for u in units_el for c in u if _local(c.tag) in ("Metric", "Imperial")]
    if not kinds:
        found = ", ".join(f"<{_local(c.tag)}>" for c in units_el[0]) or "nothing"
        raise LandXmlError(f"<Units> holds {found}; expected <Metric> or <Imperial>")
    read = [_unit_element(el) for el in kinds]
    if len(read) == 1:
        return read[0]
    listed = ", ".join(_unit_label(el) for el in kinds)
    if any(r != read[0] for r in read[1:]):
        raise LandXmlError(f"<Units> holds {len(kinds)} unit elements that disagree ({listed}): the file's numbers "
                           "are in one of them and nothing says which; keep the one the file was written in "
                           "(LandXML 1.2 allows one)")
    note = f"<Units> holds {len(kinds)} unit elements ({listed}); they agree and are used"
    return replace(read[0], note=f"{note}; {read[0].note}" if read[0].note else note)


def _unit_label(el: ET.Element) -> str:
    """``<Metric linearUnit="meter">``: how the unit messages name a unit element."""
    attrs = "".join(f' {k}="{el.get(k)}"' for k in ("linearUnit", "elevationUnit") if el.get(k) is not None)
    return f"<{_local(el.tag)}{attrs}>"


def _unit_element(el: ET.Element) -> _Units:
    """The conversions one ``<Metric>`` or ``<Imperial>`` gives."""
    kind = _local(el.tag)
    table = _METRIC_M if kind == "Metric" else _IMPERIAL_M
    lin = el.get("linearUnit")
    if lin is None:
        raise LandXmlError(f"<Units><{kind}>: missing attribute 'linearUnit'")
    if lin not in table:
        raise LandXmlError(f"<Units><{kind}>: linearUnit={lin!r} is not supported "
                           f"({', '.join(table)})")
    linear = table[lin]
    elev_name = el.get("elevationUnit")
    if elev_name is None:
        elevation = linear
    else:
        # elevationType: meter, kilometer, feet, miles; "feet" is the file's own foot
        foot = units.US_SURVEY_FOOT_M if lin == "USSurveyFoot" else units.INTERNATIONAL_FOOT_M
        table_h = {"meter": 1.0, "kilometer": 1e3, "feet": foot, "miles": units.INTERNATIONAL_MILE_M}
        if elev_name not in table_h:
            raise LandXmlError(f"<Units><{kind}>: elevationUnit={elev_name!r} is not supported "
                               f"({', '.join(table_h)})")
        elevation = table_h[elev_name]
    note = None
    if kind == "Imperial":
        note = (f"<Units><Imperial linearUnit={lin!r}>: lengths converted at {linear!r} m, "
                f"elevations at {elevation!r} m, cant values from inches")
    return _Units(linear=linear, elevation=elevation,
                  cant=units.INCH_M if kind == "Imperial" else 1e-3,
                  gauge=linear if kind == "Imperial" else 1.0, note=note)


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
def _f(x: float) -> str:
    """Shortest text that reads back to the same double."""
    return repr(float(x))


def _pt(z_n: float, z_e: float) -> str:
    return f"{_f(z_n)} {_f(z_e)}"


def _radius_text(k: float) -> str:
    return "INF" if k == 0.0 else _f(1.0 / abs(k))


def _tangent_intersection(z0: complex, h0: float, z1: complex, h1: float) -> complex:
    """Intersection of the start tangent through z0 and the end tangent through z1."""
    t0, t1 = complex(math.cos(h0), math.sin(h0)), complex(math.cos(h1), math.sin(h1))
    # z0 + a t0 = z1 - b t1; the imaginary part of conj(t1) * (...) removes b
    det = (t1.conjugate() * t0).imag
    if abs(det) < 1e-15:
        raise ValueError("the tangents of a transition are parallel; no PI")
    a = (t1.conjugate() * (z1 - z0)).imag / det
    return z0 + a * t0


def landxml_text(alignment: Alignment, *, rail_spacing_m: float = DEFAULT_RAIL_SPACING_M,
                 timestamp: _dt.datetime | None = None, project_name: str = "trolley-survey"
                 ) -> str:
    """LandXML 1.2 document holding ``alignment`` (metres, radians).

    Parameters
    ----------
    alignment : the alignment to write.
    rail_spacing_m : rail spacing turning the cant angle into ``appliedCant`` (mm); written as
        the ``gauge`` attribute of ``<Cant>``.
    timestamp : ``date``/``time`` of the document (default: now, UTC).
    project_name : ``Project/@name``.

    Returns
    -------
    str
        The document; :func:`parse_landxml` reads it back to the same geometry.

    Raises
    ------
    ValueError
        A clothoid whose curvature changes sign (LandXML's ``rot`` cannot hold it; split it at
        the inflection point).
    """
    hz = alignment.horizontal
    name = alignment.name or "ALIGNMENT"
    ts = timestamp or _dt.datetime.now(_dt.timezone.utc)
    out: list[str] = []
    w = out.append
    w('<?xml version="1.0" encoding="UTF-8"?>')
    w(f'<LandXML xmlns="{LANDXML_NS}" '
      'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
      f'xsi:schemaLocation="{LANDXML_NS} {LANDXML_NS}/LandXML-1.2.xsd" '
      f'date="{ts:%Y-%m-%d}" time="{ts:%H:%M:%S}" version="1.2" language="English" '
      'readOnly="false">')
    w('  <Units>')
    w('    <Metric areaUnit="squareMeter" linearUnit="meter" volumeUnit="cubicMeter" '
      'temperatureUnit="celsius" pressureUnit="HPA" angularUnit="radians" '
      'directionUnit="radians"/>')
    w('  </Units>')
    w(f'  <Project name={quoteattr(project_name)}/>')
    w('  <Application name="trolley-survey" version="0.1"/>')
    w(f'  <Alignments name={quoteattr(name)}>')
    w(f'    <Alignment name={quoteattr(name)} staStart="{_f(hz.start_chainage_m)}" '
      f'length="{_f(hz.length_m)}">')
    w('      <CoordGeom>')
    w('        <!-- point text is "Northing Easting" -->')
    for i, el in enumerate(hz.elements):
        s0 = hz.element_chainage_m[i]
        n0, e0 = hz.element_N_m[i], hz.element_E_m[i]
        n1, e1 = hz.element_end_N_m[i], hz.element_end_E_m[i]
        h0, h1 = hz.element_heading_rad[i], hz.element_end_heading_rad[i]
        common = f'staStart="{_f(s0)}" length="{_f(el.length_m)}"'
        if isinstance(el, Line):
            w(f'        <Line {common}>')
            w(f'          <Start>{_pt(n0, e0)}</Start>')
            w(f'          <End>{_pt(n1, e1)}</End>')
            w('        </Line>')
        elif isinstance(el, Arc):
            k = el.curvature_1_m
            if k == 0.0:
                raise ValueError(f"element {i}: an Arc of zero curvature; write a Line")
            centre = complex(n0, e0) + 1j * complex(math.cos(h0), math.sin(h0)) / k
            rot = "cw" if k > 0 else "ccw"
            w(f'        <Curve {common} radius="{_f(1.0 / abs(k))}" rot="{rot}" crvType="arc">')
            w(f'          <Start>{_pt(n0, e0)}</Start>')
            w(f'          <Center>{_pt(centre.real, centre.imag)}</Center>')
            w(f'          <End>{_pt(n1, e1)}</End>')
            w('        </Curve>')
        else:
            k0, k1 = el.curvature_start_1_m, el.curvature_end_1_m
            if k0 * k1 < 0:
                raise ValueError(f"element {i}: a clothoid through zero curvature cannot be "
                                 f"written to LandXML (split it at the inflection)")
            rot = "cw" if (k0 + k1) > 0 else "ccw"
            pi = _tangent_intersection(complex(n0, e0), h0, complex(n1, e1), h1)
            extra = ""
            if k0 == 0.0 or k1 == 0.0:
                extra = f' constant="{_f(math.sqrt(el.length_m / abs(k1 - k0)))}"'
            w(f'        <Spiral {common} radiusStart="{_radius_text(k0)}" '
              f'radiusEnd="{_radius_text(k1)}" rot="{rot}" spiType="clothoid"{extra}>')
            w(f'          <Start>{_pt(n0, e0)}</Start>')
            w(f'          <PI>{_pt(pi.real, pi.imag)}</PI>')
            w(f'          <End>{_pt(n1, e1)}</End>')
            w('        </Spiral>')
    w('      </CoordGeom>')
    if alignment.stationing is not None:
        for eq in alignment.stationing.equations:
            back = "" if eq.back_m is None else f' staBack="{_f(eq.back_m)}"'
            inc = "increasing" if eq.increasing else "decreasing"
            w(f'      <StaEquation staInternal="{_f(eq.internal_m)}" staAhead="{_f(eq.ahead_m)}"'
              f'{back} staIncrement="{inc}"/>')
    if alignment.profile is not None:
        pr = alignment.profile
        w(f'      <Profile name={quoteattr(name + "-V")}>')
        w('        <ProfAlign name="design">')
        for s, h, L, R in zip(pr.chainage_m, pr.height_m, pr.curve_length_m,
                              pr.vertical_radius_m):
            if R > 0:
                w(f'          <CircCurve length="{_f(L)}" radius="{_f(R)}">{_f(s)} {_f(h)}'
                  '</CircCurve>')
            elif L > 0:
                w(f'          <ParaCurve length="{_f(L)}">{_f(s)} {_f(h)}</ParaCurve>')
            else:
                w(f'          <PVI>{_f(s)} {_f(h)}</PVI>')
        w('        </ProfAlign>')
        w('      </Profile>')
    if alignment.cant is not None:
        ct = alignment.cant
        w(f'      <Cant name={quoteattr(name + "-CANT")} gauge="{_f(rail_spacing_m)}" '
          'rotationPoint="center">')
        for s, c in zip(ct.chainage_m, ct.cant_rad):
            mm = units.m_to_mm(rail_spacing_m * math.sin(abs(c)))
            bend = _side_of_curve(hz, s)
            side = math.copysign(1.0, c) if c != 0.0 else (bend or 1.0)
            adverse = c != 0.0 and bend == -side     # the inner rail raised: said as such
            curv = "cw" if (bend if adverse else side) > 0 else "ccw"
            w(f'        <CantStation station="{_f(s)}" appliedCant="{_f(mm)}" curvature="{curv}"'
              + (' adverse="true"/>' if adverse else '/>'))
        w('      </Cant>')
    w('    </Alignment>')
    w('  </Alignments>')
    w('</LandXML>')
    return "\n".join(out) + "\n"

