"""Generate projects/demo/cpiii.csv: CPIII pairs every 60 m along the demo design alignment.

Each pair stands abreast of chainage k * 60 m from the alignment start: one point 2 m outside
the left rail and one 2 m outside the right rail (lateral offset rail_spacing / 2 + 2 m from the
centre line), at the height of the nearer rail top (design height plus the cant lift of that
rail) + 0.3 m, as CPIII marks sit on masts or walls a little above the rails. Ids are
``CP<pair:04d>L`` and ``CP<pair:04d>R``; the simulated sessions label their stops ``CP<pair:04d>``.

Run from the repository root:  python examples/make_demo_cpiii.py
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from trolley.landxml import parse_landxml

SPACING_M = 60.0
OUTSIDE_RAIL_M = 2.0
ABOVE_RAIL_M = 0.3
RAIL_SPACING_M = 1.5


def cpiii_rows(alignment) -> list[str]:
    """CSV lines (with header) of the CPIII pairs along ``alignment``."""
    s0, s1 = alignment.start_chainage_m, alignment.end_chainage_m
    k = np.arange(int(np.floor((s1 - s0) / SPACING_M + 1e-9)) + 1)
    d = alignment.evaluate(s0 + SPACING_M * k)
    right_e, right_n = np.cos(d.heading_rad), -np.sin(d.heading_rad)   # unit vector to the right
    offset = RAIL_SPACING_M / 2 + OUTSIDE_RAIL_M
    rail_lift = RAIL_SPACING_M / 2 * np.sin(d.cant_rad)               # + cant lifts the left rail
    rows = ["id,E_m,N_m,H_m"]
    for i, pair in enumerate(k):
        for side, sign, lift in (("L", -1.0, rail_lift[i]), ("R", 1.0, -rail_lift[i])):
            e = d.E_m[i] + sign * offset * right_e[i]
            n = d.N_m[i] + sign * offset * right_n[i]
            h = d.H_m[i] + lift + ABOVE_RAIL_M
            rows.append(f"CP{pair:04d}{side},{e:.4f},{n:.4f},{h:.4f}")
    return rows


def main(argv: list[str]) -> int:
    root = Path(__file__).resolve().parents[1] / "projects" / "demo"
    alignment = parse_landxml((root / "alignment.xml").read_text(encoding="utf-8"))
    out = root / "cpiii.csv"
    out.write_text("\n".join(cpiii_rows(alignment)) + "\n", encoding="utf-8")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
