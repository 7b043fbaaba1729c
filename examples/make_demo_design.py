"""Write ``projects/demo/alignment.xml``: the demo design track, generated from its elements.

A high-speed-like alignment of 1.3 km: straight 200 m, clothoid 150 m, right-hand arc
R = 3000 m of 500 m, clothoid 150 m, straight 300 m; grades up to 0.8 % joined by parabolic
vertical curves of vertical radius 20 000 m; cant ramping linearly from 0 to 120 mm (a height
over the 1.5 m rail spacing) along the first clothoid and back to 0 along the second.

Run: ``python examples/make_demo_design.py [OUT.xml]``.
"""
from __future__ import annotations

import datetime as dt
import math
import sys
from pathlib import Path

import numpy as np

from trolley.alignment import (Alignment, Arc, CantProfile, Clothoid, HorizontalAlignment, Line,
                               VerticalProfile)
from trolley.landxml import DEFAULT_RAIL_SPACING_M, landxml_text, parse_landxml
from trolley.units import deg_to_rad, mm_to_m

RADIUS_M = 3000.0
VERTICAL_RADIUS_M = 20000.0
CANT_MM = 120.0


def demo_alignment() -> Alignment:
    """The demo design as elements (grid coordinates in a realistic projected range)."""
    k = 1.0 / RADIUS_M
    elements = [Line(200.0), Clothoid(150.0, 0.0, k), Arc(500.0, k), Clothoid(150.0, k, 0.0),
                Line(300.0)]
    hz = HorizontalAlignment.from_elements(start_E_m=500123.456, start_N_m=3100234.567,
                                           start_heading_rad=deg_to_rad(60.0),
                                           elements=elements, start_chainage_m=0.0)
    pvi_s = np.array([0.0, 400.0, 900.0, 1300.0])
    pvi_h = np.array([50.0, 53.2, 50.7, 51.9])  # grades +0.8 %, -0.5 %, +0.3 %
    grades = np.diff(pvi_h) / np.diff(pvi_s)
    curve = np.zeros_like(pvi_s)
    # L = R_v |delta g|, rounded to the millimetre as a designer would write it
    curve[1:-1] = np.round(VERTICAL_RADIUS_M * np.abs(np.diff(grades)), 3)
    profile = VerticalProfile.from_pvis(pvi_s, pvi_h, curve)
    cant_rad = math.asin(mm_to_m(CANT_MM) / DEFAULT_RAIL_SPACING_M)
    ts = hz.element_chainage_m  # cant ramps along the two clothoids
    cant = CantProfile.from_stations([ts[1], ts[2], ts[3], ts[4]], [0.0, cant_rad, cant_rad, 0.0])
    return Alignment(hz, profile, cant, name="DEMO-UP")


def main(argv: list[str]) -> None:
    out = Path(argv[1]) if len(argv) > 1 else Path(__file__).resolve().parents[1] / "projects" / "demo" / "alignment.xml"
    alignment = demo_alignment()
    text = landxml_text(alignment, timestamp=dt.datetime(2026, 11, 23, 12, 0, 0),
                        project_name="trolley-survey demo")
    back = parse_landxml(text)  # never write a file we cannot read back
    s = np.linspace(alignment.start_chainage_m, alignment.end_chainage_m, 2601)
    a, b = alignment.evaluate(s), back.evaluate(s)
    worst = max(np.max(np.abs(a.E_m - b.E_m)), np.max(np.abs(a.N_m - b.N_m)),
                np.max(np.abs(a.H_m - b.H_m)))
    if worst > 1e-6:
        raise SystemExit(f"round trip through LandXML moved the alignment by {worst:.3g} m")
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(out)
    print(f"wrote {out} ({alignment.end_chainage_m - alignment.start_chainage_m:.1f} m, "
          f"round trip {worst:.2g} m)", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv)
