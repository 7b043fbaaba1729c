"""Writes the real-style LandXML fixtures of tests/test_landxml_real.py (run once; the files are
committed). Coordinates are rounded to 0.1 mm and stations to 1 mm, as design tools write them.

Base geometry ("REAL"): grid N 5 600 000, E 400 000 (UTM-sized numbers), a 250 m straight on
bearing 60 deg, a 200 m circular arc of radius 800 m turning right, a 300 m straight. Start
station 1000.
"""
from __future__ import annotations

import math
from pathlib import Path

HERE = Path(__file__).resolve().parent
N0, E0, B0 = 5_600_000.0, 400_000.0, math.radians(60.0)
L1, R, LA, L2 = 250.0, 800.0, 200.0, 300.0
HEAD = """<?xml version="1.0" encoding="UTF-8"?>
<LandXML xmlns="http://www.landxml.org/schema/LandXML-1.2" date="2024-03-11" time="14:02:10" version="1.2">
  <Units>
    <{units}/>
  </Units>
  <Project name="fixture"/>
  <Application name="design tool" version="1"/>
"""
METRIC = ('Metric areaUnit="squareMeter" linearUnit="meter" volumeUnit="cubicMeter" '
          'temperatureUnit="celsius" pressureUnit="HPA"')


def pt(n: float, e: float, scale: float = 1.0) -> str:
    return f"{n / scale:.4f} {e / scale:.4f}"


def real_elements(scale: float = 1.0, sta0: float = 1000.0, breaks: tuple[float, float] = (0.0, 0.0),
                  zero_curve: bool = False, feature: bool = False, shift_e: float = 0.0) -> str:
    """CoordGeom of the base geometry; ``breaks`` turns the arc's and the last straight's start
    direction by these angles (rad) against the end of the element before (direction breaks);
    ``shift_e`` moves it east (a second track)."""
    b = B0
    n0, e0 = N0, E0 + shift_e
    a_n, a_e = n0 + L1 * math.cos(b), e0 + L1 * math.sin(b)
    b_arc = b + breaks[0]
    c_n, c_e = a_n + R * math.cos(b_arc + math.pi / 2), a_e + R * math.sin(b_arc + math.pi / 2)
    phi = b_arc - math.pi / 2 + LA / R
    d_n, d_e = c_n + R * math.cos(phi), c_e + R * math.sin(phi)
    b2 = b_arc + LA / R + breaks[1]
    f_n, f_e = d_n + L2 * math.cos(b2), d_e + L2 * math.sin(b2)
    s = scale
    out = ["      <CoordGeom>"]
    if feature:
        out.append('        <Feature code="ProVI" name="Gleis 1"><Property label="Gleisart" value="Hauptgleis"/></Feature>')
    out += [f'        <Line staStart="{sta0 / s:.3f}" length="{L1 / s:.4f}">',
            f"          <Start>{pt(n0, e0, s)}</Start>", f"          <End>{pt(a_n, a_e, s)}</End>"]
    if feature:
        out.append('          <Feature code="ProVI"><Property label="Element" value="G"/></Feature>')
    out.append("        </Line>")
    if zero_curve:
        out += [f'        <Curve staStart="{(sta0 + L1) / s:.3f}" length="0.0000" radius="{R / s:.4f}" rot="cw" crvType="arc">',
                f"          <Start>{pt(a_n, a_e, s)}</Start>", f"          <Center>{pt(c_n, c_e, s)}</Center>",
                f"          <End>{pt(a_n, a_e, s)}</End>", "        </Curve>"]
    if feature:
        out.append('        <pv:Trasse xmlns:pv="urn:example:vendor-extension" typ="Gerade"/>')
    out += [f'        <Curve staStart="{(sta0 + L1) / s:.3f}" length="{LA / s:.4f}" radius="{R / s:.4f}" rot="cw" crvType="arc">',
            f"          <Start>{pt(a_n, a_e, s)}</Start>", f"          <Center>{pt(c_n, c_e, s)}</Center>",
            f"          <End>{pt(d_n, d_e, s)}</End>", "        </Curve>",
            f'        <Line staStart="{(sta0 + L1 + LA) / s:.3f}" length="{L2 / s:.4f}">',
            f"          <Start>{pt(d_n, d_e, s)}</Start>", f"          <End>{pt(f_n, f_e, s)}</End>", "        </Line>",
            "      </CoordGeom>"]
    return "\n".join(out)


def profile(pvis: list[tuple[str, float, float, float]], scale: float = 1.0, feature: bool = False) -> str:
    out = ['      <Profile name="FGL">', '        <ProfAlign name="Gradiente">']
    for kind, s, h, length in pvis:
        if kind == "PVI":
            out.append(f"          <PVI>{s / scale:.3f} {h / scale:.4f}</PVI>")
        else:
            out.append(f'          <ParaCurve length="{length / scale:.4f}">{s / scale:.3f} {h / scale:.4f}</ParaCurve>')
    if feature:
        out.append('          <Feature code="ProVI"><Property label="Neigungswechsel" value="3"/></Feature>')
    out += ["        </ProfAlign>", "      </Profile>"]
    return "\n".join(out)


def cant(stations: list[tuple[float, float]], gauge: str = "1.500") -> str:
    out = [f'      <Cant name="Ueberhoehung" gauge="{gauge}" rotationPoint="insideRail">']
    out += [f'        <CantStation station="{s:.3f}" appliedCant="{c:g}" curvature="cw"/>' for s, c in stations]
    out.append("      </Cant>")
    return "\n".join(out)


def alignment(name: str, body: str, sta0: float, length: float, extra: str = "") -> str:
    return (f'    <Alignment name="{name}" staStart="{sta0:.3f}" length="{length:.4f}">\n{body}\n'
            + (extra + "\n" if extra else "") + "    </Alignment>")


def document(alignments: list[str], units: str = METRIC, name: str = "Gleise") -> str:
    return (HEAD.format(units=units) + f'  <Alignments name="{name}">\n' + "\n".join(alignments)
            + "\n  </Alignments>\n</LandXML>\n")


REAL_PROFILE = [("PVI", 1000.0, 100.0, 0.0), ("ParaCurve", 1300.0, 103.0, 200.0),
                ("ParaCurve", 1500.0, 101.0, 200.0), ("PVI", 1750.0, 102.0, 0.0)]
REAL_CANT = [(1230.0, 0.0), (1250.0, 80.0), (1450.0, 80.0), (1470.0, 0.0)]


def main() -> None:
    total = L1 + LA + L2
    files = {}
    geom = real_elements()
    # three alignments in one file (track 1, track 2, a siding)
    down = real_elements(shift_e=-4.5)
    siding = ("      <CoordGeom>\n        <Line staStart=\"0.000\" length=\"120.0000\">\n"
              f"          <Start>{pt(N0 - 10.0, E0)}</Start>\n          <End>{pt(N0 - 10.0, E0 + 120.0)}</End>\n"
              "        </Line>\n      </CoordGeom>")
    files["several_alignments.xml"] = document([
        alignment("Gleis 1", geom, 1000.0, total, profile(REAL_PROFILE) + "\n" + cant(REAL_CANT)),
        alignment("Gleis 2", down.replace('<Line staStart="1000.000" length="250.0000">',
                                          '<Line staStart="1000.000" length="250.0000" name="G2-1">'), 1000.0, total),
        alignment("Abstellgleis 3", siding, 0.0, 120.0)])
    # Feature in CoordGeom, in a Line, in ProfAlign and in the Alignment; a vendor extension
    files["feature_and_extensions.xml"] = document([alignment(
        "Gleis 1", real_elements(feature=True), 1000.0, total,
        profile(REAL_PROFILE, feature=True) + "\n" + cant(REAL_CANT)
        + '\n      <Feature code="ProVI"><Property label="Streckennummer" value="6100"/></Feature>'
        + '\n      <Superelevation staStart="1000.0" staEnd="1750.0"/>')])
    # station equation at internal 1300: the drawing jumps to 2300 (km-post break); cant and
    # PVI stations after it are given in the drawing stationing, as ProVI writes them
    eq = '      <StaEquation staInternal="1300.000" staBack="1300.000" staAhead="2300.000" staIncrement="increasing"/>'
    files["station_equation.xml"] = document([alignment(
        "Gleis 1", geom, 1000.0, total,
        eq + "\n" + profile([("PVI", 1000.0, 100.0, 0.0), ("ParaCurve", 1200.0, 103.0, 100.0),
                             ("ParaCurve", 2500.0, 101.0, 200.0), ("PVI", 2750.0, 102.0, 0.0)])
        + "\n" + cant([(1230.0, 0.0), (1250.0, 80.0), (2450.0, 80.0), (2470.0, 0.0)]))])
    # the same with a cant station 10 m beyond the end (drawing 2760 = internal 1760 > 1750)
    files["cant_beyond_end.xml"] = document([alignment(
        "Gleis 1", geom, 1000.0, total,
        eq + "\n" + cant([(1230.0, 0.0), (1250.0, 80.0), (2450.0, 80.0), (2470.0, 0.0), (2760.0, 0.0)]))])
    # imperial: the base geometry in US survey feet, and the same numbers read as international feet
    us = 1200.0 / 3937.0
    us_units = ('Imperial areaUnit="squareFoot" linearUnit="USSurveyFoot" volumeUnit="cubicYard" '
                'temperatureUnit="fahrenheit" pressureUnit="inHG" elevationUnit="feet"')
    body_ft = real_elements(scale=us)
    prof_ft = profile(REAL_PROFILE, scale=us)
    cant_ft = ('      <Cant name="SE" gauge="4.7083" rotationPoint="insideRail">\n'
               + "\n".join(f'        <CantStation station="{s / us:.3f}" appliedCant="{c / 25.4:.4f}" curvature="cw"/>'
                           for s, c in REAL_CANT) + "\n      </Cant>")
    ft_align = (f'    <Alignment name="Track 1" staStart="{1000.0 / us:.3f}" length="{total / us:.4f}">\n'
                f"{body_ft}\n{prof_ft}\n{cant_ft}\n    </Alignment>")
    files["imperial_us_survey_foot.xml"] = document([ft_align], units=us_units, name="Tracks")
    files["imperial_international_foot.xml"] = document(
        [ft_align], units=us_units.replace('linearUnit="USSurveyFoot"', 'linearUnit="foot"'), name="Tracks")
    # direction breaks of 2e-5 rad at both joins (each element's own Start and direction)
    files["direction_breaks.xml"] = document([alignment("Gleis 1", real_elements(breaks=(2e-5, 2e-5)),
                                                        1000.0, total)])
    files["direction_break_large.xml"] = document([alignment("Gleis 1", real_elements(breaks=(0.0, 3e-4)),
                                                             1000.0, total)])
    # a zero-length curve between the first straight and the arc
    files["zero_length_curve.xml"] = document([alignment("Gleis 1", real_elements(zero_curve=True), 1000.0, total)])
    # vertical curves overlapping by 0.4 mm (lengths rounded up by the tool), and by 5 mm
    overlap = [("PVI", 1000.0, 100.0, 0.0), ("ParaCurve", 1300.0, 103.0, 200.0),
               ("ParaCurve", 1500.0, 101.0, 200.0008), ("PVI", 1750.0, 102.0, 0.0)]
    files["overlapping_vertical_curves.xml"] = document([alignment("Gleis 1", geom, 1000.0, total, profile(overlap))])
    overlap[2] = ("ParaCurve", 1500.0, 101.0, 200.01)
    files["overlapping_vertical_curves_5mm.xml"] = document([alignment("Gleis 1", geom, 1000.0, total,
                                                                       profile(overlap))])
    # a declared length 0.5 m longer than the elements
    files["wrong_declared_length.xml"] = document([alignment("Gleis 1", geom, 1000.0, total + 0.5)])
    for name, text in files.items():
        (HERE / name).write_text(text, encoding="utf-8")


if __name__ == "__main__":
    main()
