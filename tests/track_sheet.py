"""Finding the table of the workbook's Track sheet (not a test module).

The Track sheet starts with the header block every sheet carries; its column header row is the
row whose first cell is the chainage column's name, and the station rows follow it. The tests
locate that row instead of assuming a row number.
"""
from __future__ import annotations

CHAINAGE_HEADER = "Chainage [m]"


def track_table(ws) -> tuple[int, list]:
    """(row number of the column header row, its values) of a Track sheet ``ws``."""
    for row in ws.iter_rows(min_col=1, max_col=1):
        if row[0].value == CHAINAGE_HEADER:
            r = row[0].row
            return r, [c.value for c in ws[r]]
    raise AssertionError(f"no row starting with {CHAINAGE_HEADER!r} on sheet {ws.title!r}")
