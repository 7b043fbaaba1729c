"""Numbers written as text in the files the project reads (CSV cells, LandXML values, GSI words).

Python's ``float()`` (and numpy's, which uses it for text) reads more than a file's number: any
Unicode decimal digit (full-width ``５``, Arabic-Indic ``٥``, ...) and digit grouping with ``_``
(``1_000``). A coordinate with such a character was changed by some tool (an input method, a
spreadsheet with another locale, a copy from a web page); the value read may be right or not, and
nothing tells which. Every reader of numbers in text applies the one rule here: a number is
written in ASCII without ``_``, anything else is refused naming the character.
"""
from __future__ import annotations

import unicodedata

#: Characters of a bad cell quoted in a message (a cell may hold a whole pasted paragraph).
_QUOTED_CHARS = 40


def foreign_character(text: str) -> str | None:
    """The first character of ``text`` that ``float()`` would read but a number in a file must not
    hold, described for an error message (``'５' (U+FF15 FULLWIDTH DIGIT FIVE)...``); None when
    there is none. Only the characters are checked, not the grammar (``float()`` does that)."""
    if text.isascii() and "_" not in text:
        return None
    for ch in text:
        if ch == "_":
            return "'_' (digit grouping): a number in a file is written without it"
        if not ch.isascii():
            return (f"{ch!r} (U+{ord(ch):04X} {unicodedata.name(ch, 'unnamed character')}) is not ASCII: "
                    "a number is written with the digits 0-9 (was the file changed by some tool?)")
    return None


def parse_number(text: str) -> float:
    """``float(text)`` for a number read from a file: refused (ValueError) when ``text`` holds a
    character :func:`foreign_character` names, or is not a number at all. The message starts with
    the text (``'５00' is not a number: ...``), for the caller to put after the file, row and
    column (at most 40 characters of it). NaN and infinities are returned: whether they are allowed is the caller's rule."""
    problem = foreign_character(text)
    quoted = repr(text) if len(text) <= _QUOTED_CHARS else repr(text[:_QUOTED_CHARS]) + "..."
    if problem is not None:
        raise ValueError(f"{quoted} is not a number: {problem}")
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"{quoted} is not a number") from None


def all_plain(texts) -> bool:
    """True when no text of ``texts`` holds a character :func:`foreign_character` names: the check
    of a whole column parsed in one go (numpy), before a cell-by-cell search for the bad one."""
    joined = "".join(texts)
    return joined.isascii() and "_" not in joined
