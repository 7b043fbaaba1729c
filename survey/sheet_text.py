"""Text that is safe in spreadsheets: no formula injection, no illegal control characters.

Text from users and files (point labels, notes, project names, reasons) must never become a
formula or crash the writer (shared/research/protocols.md 6.2, OWASP ASVS 1.2.10, CWE-1236):

* control characters that XML 1.0 cannot hold (\\x00-\\x08, \\x0b, \\x0c, \\x0e-\\x1f, \\x7f)
  are escaped as visible ``\\xNN`` text;
* in .xlsx, every such cell is stored as a string (never ``data_type='f'``, never an error
  literal) and text that starts with ``=``, ``+``, ``-``, ``@``, TAB or CR also gets the
  ``quotePrefix`` style, so Excel keeps it text even when the user edits the cell;
* in CSV, such text is prefixed with a single quote ``'`` (the OWASP recommendation).
  Numbers are written as numbers, never quoted: a negative number is not an injection.
"""
from __future__ import annotations

import re

#: Leading characters that make spreadsheet programs evaluate a cell.
FORMULA_LEAD = ("=", "+", "-", "@", "\t", "\r")

_ILLEGAL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")


def clean_text(value: object) -> str:
    """``str(value)`` with XML-illegal control characters escaped as ``\\xNN``."""
    text = "" if value is None else str(value)
    return _ILLEGAL.sub(lambda m: f"\\x{ord(m.group()):02x}", text)


def needs_quote_prefix(text: str) -> bool:
    """True when a spreadsheet program would read ``text`` as a formula."""
    return text.startswith(FORMULA_LEAD)


def csv_safe_text(value: object) -> str:
    """Text for a CSV cell: cleaned, and prefixed with ``'`` when it would start a formula."""
    text = clean_text(value)
    return "'" + text if needs_quote_prefix(text) else text


def csv_read_text(text: str) -> str:
    """Undo :func:`csv_safe_text`'s quote prefix when reading a CSV cell back."""
    return text[1:] if text.startswith("'") and needs_quote_prefix(text[1:]) else text


def put_text(ws, row: int, column: int, value: object):
    """Write ``value`` as a text cell into an openpyxl worksheet (never a formula).

    Returns the cell.
    """
    text = clean_text(value)[:32767]
    if not text:
        return ws.cell(row=row, column=column)
    cell = ws.cell(row=row, column=column, value=text)
    cell.data_type = "s"
    if needs_quote_prefix(text):
        cell.quotePrefix = True
    return cell
