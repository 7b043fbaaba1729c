"""LandXML 1.2 design alignments: read ``<Alignment>`` into :class:`~trolley.alignment.Alignment`
and write one back.

What is read (schema LandXML-1.2.xsd; see ``docs/conventions.md``, "Design geometry"):

- ``<CoordGeom>``: ``<Line>``, ``<Curve>`` (circular arc, Start/Center/End) and ``<Spiral>``
  with ``spiType="clothoid"``. Point text is "Northing Easting [Elevation]" (the elevation is
  ignored). Directions (``dir``, ``dirStart``, ...) are NOT trusted: every heading is recomputed
  from coordinates (Line: Start->End; Curve: the radius Center->Start and ``rot``; Spiral:
  Start->PI). Line and arc lengths and the arc radius come from the coordinates too; the
  clothoid takes ``length``, ``radiusStart``, ``radiusEnd`` (``INF`` = straight) and ``rot``.
  The elements are chained from the first one's start point and heading, and every Start and
  End in the file must lie within 1 mm of the chained geometry.
- ``<Profile>/<ProfAlign>`` (the first one): ``<PVI>`` and ``<ParaCurve length>`` ("station
  elevation"); ``<CircCurve length radius>`` is an exact circle of that radius tangent to both
  grades (crest or sag from the grades, whatever the sign of the radius); its ``length`` must
  agree with the circle's arc length within max(0.1 m, 1 %).
- ``<Cant>/<CantStation>``: ``appliedCant`` (mm, a rail height difference) is converted to the
  cant angle asin(appliedCant / rail_spacing); its sign follows ``curvature`` (``cw``, a
  right-hand curve, raises the left rail: positive), flipped when ``adverse="true"``. Ramps
  between stations are linear (``transitionType`` absent, ``linear`` or ``clothoid``).

Anything else that changes the geometry (other spiral types, ``UnsymParaCurve``, imperial units,
point references) is refused with :class:`LandXmlError` naming the element. Station equations
(``<StaEquation>``) are not applied: chainages are internal stations (staStart + distance).

References
----------
LandXML-1.2 schema, http://www.landxml.org/schema/LandXML-1.2/LandXML-1.2.xsd (Alignment,
Spiral, Curve, Profile, Cant and CantStation documentation pages).
"""
from __future__ import annotations

import datetime as _dt
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np

from trolley import units
from trolley.alignment import (Alignment, Arc, CantProfile, Clothoid, HorizontalAlignment, Line,
                               VerticalProfile)

__all__ = ["LandXmlError", "parse_landxml", "landxml_text", "JOIN_TOLERANCE_M",
           "DEFAULT_RAIL_SPACING_M", "CoordinateSystemInfo", "coordinate_system"]

LANDXML_NS = "http://www.landxml.org/schema/LandXML-1.2"
#: Largest gap allowed between consecutive elements, or between the coordinates in the file and
#: the geometry recomputed from them.
JOIN_TOLERANCE_M = 1e-3
#: Distance between rail centre lines used to turn appliedCant (a height) into an angle.
DEFAULT_RAIL_SPACING_M = 1.5

_LINEAR_UNIT_M = {"meter": 1.0, "millimeter": 1e-3, "centimeter": 1e-2, "kilometer": 1e3}
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
        value = float(text.strip())
    except ValueError:
        raise LandXmlError(f"{where}: {what}={text!r} is not a number") from None
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
            v = float(p)
        except ValueError:
            raise LandXmlError(f"{where}: <{_local(el.tag)}> value {p!r} is not a number") from None
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


def _parse_line(el, where, scale) -> _ParsedElement:
    start = _point(el, "Start", where, scale)
    end = _point(el, "End", where, scale)
    length = abs(end - start)
    if length <= 0.0:
        raise LandXmlError(f"{where}: Start and End coincide")
    _check_attr_length(el, where, scale, length)
    return _ParsedElement(Line(length), start, end, _bearing(end - start), _sta(el, where, scale),
                          where)


def _parse_curve(el, where, scale) -> _ParsedElement:
    sign = _rot_sign(el, where)
    if el.get("crvType") not in (None, "arc", "chord"):
        raise LandXmlError(f"{where}: crvType={el.get('crvType')!r} is not supported")
    start = _point(el, "Start", where, scale)
    centre = _point(el, "Center", where, scale)
    end = _point(el, "End", where, scale)
    radius = abs(start - centre)
    if radius <= 0.0:
        raise LandXmlError(f"{where}: Center coincides with Start")
    if abs(abs(end - centre) - radius) > JOIN_TOLERANCE_M:
        raise LandXmlError(f"{where}: End is {abs(end - centre):.4f} m from Center but Start is "
                           f"{radius:.4f} m: not a circular arc")
    if el.get("radius") is not None:
        r_attr = abs(_finite(el.get("radius"), where, "radius")) * scale
        if abs(r_attr - radius) > JOIN_TOLERANCE_M:
            raise LandXmlError(f"{where}: radius={el.get('radius')} disagrees with the coordinates "
                               f"(|Start - Center| = {radius:.4f} m)")
    # multiplying N + iE by exp(i a) turns clockwise: the swept angle in the rot direction
    swept = (sign * math.atan2(((end - centre) / (start - centre)).imag,
                               ((end - centre) / (start - centre)).real)) % (2.0 * math.pi)
    length = radius * swept
    if length <= 0.0:
        raise LandXmlError(f"{where}: Start and End coincide")
    _check_attr_length(el, where, scale, length)
    # the centre lies to the right of the direction of travel for cw, to the left for ccw
    tangent = (centre - start) / (1j * sign * radius)
    return _ParsedElement(Arc(length, sign / radius), start, end, _bearing(tangent),
                          _sta(el, where, scale), where)


def _parse_spiral(el, where, scale) -> _ParsedElement:
    spi = el.get("spiType")
    if spi is None:
        raise LandXmlError(f"{where}: missing attribute 'spiType'")
    if spi != "clothoid":
        raise LandXmlError(f"{where}: spiType={spi!r} is not supported (only 'clothoid')")
    sign = _rot_sign(el, where)
    length = _finite(el.get("length"), where, "length") * scale
    if length <= 0.0:
        raise LandXmlError(f"{where}: length={el.get('length')!r} must be > 0")
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
                          _sta(el, where, scale), where)


def _sta(el, where, scale) -> float | None:
    text = el.get("staStart")
    return None if text is None else _finite(text, where, "staStart") * scale


def _check_attr_length(el, where, scale, length) -> None:
    if el.get("length") is not None:
        l_attr = _finite(el.get("length"), where, "length") * scale
        if abs(l_attr - length) > JOIN_TOLERANCE_M:
            raise LandXmlError(f"{where}: length={el.get('length')} disagrees with the coordinates "
                               f"({length:.4f} m)")


_PARSERS = {"Line": _parse_line, "Curve": _parse_curve, "Spiral": _parse_spiral}


def _horizontal(al: ET.Element, aname: str, scale: float, sta_start: float) -> HorizontalAlignment:
    geoms = _children(al, "CoordGeom")
    if not geoms:
        raise LandXmlError(f"{aname}: no <CoordGeom>")
    parsed: list[_ParsedElement] = []
    for i, el in enumerate(geoms[0]):
        tag = _local(el.tag)
        if not tag:  # comments, processing instructions
            continue
        where = f"{aname}, CoordGeom {_describe(el, i)}"
        if tag not in _PARSERS:
            raise LandXmlError(f"{where}: element type <{tag}> is not supported "
                               f"(Line, Curve, Spiral)")
        if parsed:  # a gap is the first thing to report, before any disagreement it causes
            gap = abs(_point(el, "Start", where, scale) - parsed[-1].end)
            if gap > JOIN_TOLERANCE_M:
                raise LandXmlError(f"{where}: Start is {units.m_to_mm(gap):.1f} mm from the End of the "
                                   f"previous element: the elements do not join")
        parsed.append(_PARSERS[tag](el, where, scale))
    if not parsed:
        raise LandXmlError(f"{aname}: <CoordGeom> holds no Line, Curve or Spiral")
    first = parsed[0]
    try:
        hz = HorizontalAlignment.from_elements(first.start.imag, first.start.real, first.heading,
                                               [p.element for p in parsed], sta_start)
    except ValueError as exc:
        raise LandXmlError(f"{aname}: {exc}") from None
    for i, p in enumerate(parsed):
        # the element's own direction (from its coordinates) against the chained tangent: a
        # kink moves the far end of the element by about angle * length
        turn = math.remainder(p.heading - hz.element_heading_rad[i], 2.0 * math.pi)
        if abs(turn) * max(p.element.length_m, 1.0) > JOIN_TOLERANCE_M:
            raise LandXmlError(f"{p.where}: its start direction from the coordinates differs from "
                               f"the tangent of the previous element by {turn:.3g} rad, moving its "
                               f"far end by {units.m_to_mm(abs(turn) * p.element.length_m):.1f} mm "
                               f"(a kink)")
        start = complex(hz.element_N_m[i], hz.element_E_m[i])
        end = complex(hz.element_N_m[i + 1], hz.element_E_m[i + 1])
        for label, file_pt, geom_pt in (("Start", p.start, start), ("End", p.end, end)):
            miss = abs(file_pt - geom_pt)
            if miss > JOIN_TOLERANCE_M:
                raise LandXmlError(f"{p.where}: the geometry chained from the previous elements "
                                   f"reaches its {label} {units.m_to_mm(miss):.1f} mm away from the "
                                   f"coordinates in the file (a kink or a gap)")
        if p.sta_start is not None and abs(p.sta_start - hz.element_chainage_m[i]) > JOIN_TOLERANCE_M:
            raise LandXmlError(f"{p.where}: staStart does not follow the previous element "
                               f"(expected {hz.element_chainage_m[i]:.4f})")
    return hz


def _profile(al: ET.Element, aname: str, scale: float) -> VerticalProfile | None:
    for prof in _children(al, "Profile"):
        aligns = _children(prof, "ProfAlign")
        if not aligns:
            continue
        pa = aligns[0]
        pwhere = f"{aname}, {_describe(prof)} {_describe(pa)}"
        sta, elev, length, radius, wheres = [], [], [], [], []
        for i, el in enumerate(pa):
            tag = _local(el.tag)
            if not tag:
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
            elev.append(h * scale)
            length.append(curve)
            radius.append(r)
            wheres.append(where)
        if len(sta) < 2:
            raise LandXmlError(f"{pwhere}: needs at least two PVIs")
        for k in (0, len(sta) - 1):
            if length[k] != 0.0 or radius[k] != 0.0:
                raise LandXmlError(f"{wheres[k]}: the first and last PVI cannot carry a curve")
        try:
            profile = VerticalProfile.from_pvis(sta, elev, length, radius)
        except ValueError as exc:
            raise LandXmlError(f"{pwhere}: {exc}") from None
        for k in np.flatnonzero(np.asarray(radius) > 0):
            # the circle is fixed by the radius and the grades; its length is only a check
            # (PVI heights rounded to the mm move it by centimetres on long curves)
            if abs(profile.curve_length_m[k] - length[k]) > max(0.1, 0.01 * length[k]):
                raise LandXmlError(f"{wheres[k]}: length={length[k]!r} but a circle of radius "
                                   f"{radius[k]!r} between the adjacent grades is "
                                   f"{profile.curve_length_m[k]:.3f} m long")
        return profile
    return None


def _cant(al: ET.Element, aname: str, hz: HorizontalAlignment, scale: float,
          rail_spacing_m: float | None) -> CantProfile | None:
    cants = _children(al, "Cant")
    if not cants:
        return None
    cant_el = cants[0]
    cwhere = f"{aname}, {_describe(cant_el)}"
    if rail_spacing_m is None:
        # the schema gives gauge in metres whatever the linear unit
        rail_spacing_m = _finite(cant_el.get("gauge"), cwhere, "gauge")
    if not rail_spacing_m > 0:
        raise LandXmlError(f"{cwhere}: rail spacing {rail_spacing_m!r} must be > 0")
    sta, ang = [], []
    for i, el in enumerate(_children(cant_el, "CantStation")):
        where = f"{cwhere} {_describe(el, i)}"
        s = _finite(el.get("station"), where, "station") * scale
        height_m = units.mm_to_m(_finite(el.get("appliedCant"), where, "appliedCant"))
        if abs(height_m) >= rail_spacing_m:
            raise LandXmlError(f"{where}: appliedCant={el.get('appliedCant')} mm exceeds the rail "
                               f"spacing {rail_spacing_m} m")
        trans = el.get("transitionType")
        if trans is not None and trans not in _LINEAR_CANT_TRANSITIONS:
            raise LandXmlError(f"{where}: transitionType={trans!r} is not supported (linear ramps)")
        curv = el.get("curvature")
        if curv is None:
            sign = _side_of_curve(hz, s)
            if sign == 0.0 and height_m != 0.0:
                raise LandXmlError(f"{where}: missing attribute 'curvature' and no horizontal curve "
                                   f"at this station to take the side from")
        elif curv in ("cw", "ccw"):
            sign = 1.0 if curv == "cw" else -1.0
        else:
            raise LandXmlError(f"{where}: curvature={curv!r}, expected 'cw' or 'ccw'")
        adverse = el.get("adverse")
        if adverse is not None:
            if adverse not in ("true", "false", "1", "0"):
                raise LandXmlError(f"{where}: adverse={adverse!r} is not a boolean")
            if adverse in ("true", "1"):
                sign = -sign
        sta.append(s)
        ang.append(sign * math.asin(height_m / rail_spacing_m))
    if not sta:
        raise LandXmlError(f"{cwhere}: no <CantStation>")
    try:
        return CantProfile.from_stations(sta, ang)
    except ValueError as exc:
        raise LandXmlError(f"{cwhere}: {exc}") from None


def _side_of_curve(hz: HorizontalAlignment, s: float) -> float:
    """Sign of the horizontal curvature at (or just either side of) chainage ``s``."""
    k = hz.evaluate(np.array([s, s + 1e-3, s - 1e-3])).rho_h_1_m
    nz = k[k != 0.0]
    return float(np.sign(nz[0])) if nz.size else 0.0


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
    root = _parse_root(text)
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


def parse_landxml(text: str, alignment_name: str | None = None, *,
                  rail_spacing_m: float | None = DEFAULT_RAIL_SPACING_M) -> Alignment:
    """Read one ``<Alignment>`` of a LandXML 1.2 document.

    Parameters
    ----------
    text : the XML document.
    alignment_name : ``Alignment/@name`` to read; may be omitted when the file holds one.
    rail_spacing_m : distance between the rail centre lines that turns ``appliedCant`` (mm)
        into the cant angle asin(appliedCant / rail_spacing); ``None`` uses the ``gauge``
        attribute of ``<Cant>``.

    Returns
    -------
    Alignment
        Horizontal alignment, the first ``<ProfAlign>`` (if any) and ``<Cant>`` (if any).

    Raises
    ------
    LandXmlError
        Malformed XML, missing or malformed attributes, unsupported element types, or elements
        that do not join within :data:`JOIN_TOLERANCE_M`. The message names the element.
    """
    root = _parse_root(text)
    scale = _linear_scale(root)
    found = [el for el in root.iter() if _local(el.tag) == "Alignment"]
    if not found:
        raise LandXmlError("no <Alignment> in the file")
    if alignment_name is None:
        if len(found) > 1:
            names = ", ".join(repr(a.get("name")) for a in found)
            raise LandXmlError(f"the file holds {len(found)} alignments ({names}); choose one by name")
        al = found[0]
    else:
        chosen = [a for a in found if a.get("name") == alignment_name]
        if not chosen:
            names = ", ".join(repr(a.get("name")) for a in found)
            raise LandXmlError(f"no <Alignment name={alignment_name!r}> (found {names})")
        al = chosen[0]
    aname = f"<Alignment name={al.get('name')!r}>"
    for attr in ("name", "staStart", "length"):
        if al.get(attr) is None:
            raise LandXmlError(f"{aname}: missing attribute {attr!r}")
    sta_start = _finite(al.get("staStart"), aname, "staStart") * scale
    length = _finite(al.get("length"), aname, "length") * scale
    hz = _horizontal(al, aname, scale, sta_start)
    if abs(hz.length_m - length) > JOIN_TOLERANCE_M:
        raise LandXmlError(f"{aname}: length={al.get('length')} but its elements add up to "
                           f"{hz.length_m:.4f} m")
    profile = _profile(al, aname, scale)
    cant = _cant(al, aname, hz, scale, rail_spacing_m)
    return Alignment(hz, profile, cant, name=al.get("name") or "")


def _linear_scale(root: ET.Element) -> float:
    units_el = [el for el in root if _local(el.tag) == "Units"]
    if not units_el:
        raise LandXmlError("missing <Units>")
    metric = _children(units_el[0], "Metric")
    if not metric:
        kinds = ", ".join(f"<{_local(c.tag)}>" for c in units_el[0]) or "nothing"
        raise LandXmlError(f"<Units> holds {kinds}; only <Metric> is supported")
    lin = metric[0].get("linearUnit")
    if lin is None:
        raise LandXmlError("<Units><Metric>: missing attribute 'linearUnit'")
    if lin not in _LINEAR_UNIT_M:
        raise LandXmlError(f"<Units><Metric>: linearUnit={lin!r} is not supported")
    return _LINEAR_UNIT_M[lin]


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
        n1, e1 = hz.element_N_m[i + 1], hz.element_E_m[i + 1]
        h0, h1 = hz.element_heading_rad[i], hz.element_heading_rad[i + 1]
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
            side = math.copysign(1.0, c) if c != 0.0 else (_side_of_curve(hz, s) or 1.0)
            curv = "cw" if side > 0 else "ccw"
            w(f'        <CantStation station="{_f(s)}" appliedCant="{_f(mm)}" curvature="{curv}"/>')
        w('      </Cant>')
    w('    </Alignment>')
    w('  </Alignments>')
    w('</LandXML>')
    return "\n".join(out) + "\n"

